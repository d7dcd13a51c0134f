"""scenarios.reproduce: the episodes a budget asks for, and its options' errors."""

from collections import Counter

import pytest

from scenarios import WORLDS
from scenarios.reproduce import TABLE4_LINKS, budget_from, main, parse_args, sweep_episodes


def test_table4_runs_every_controller_seed_in_every_environment_once():
    budget = budget_from(parse_args(["table4", "--seeds", "2", "--env-seeds", "3"]))
    episodes = sweep_episodes("table4", budget)
    keys = Counter((s.scenario, s.links, s.controller, s.env_seed, s.seed) for s in episodes)
    assert set(keys.values()) == {1}
    assert {k[0] for k in keys} == {"cluttered"} and {k[1] for k in keys} == set(TABLE4_LINKS)
    assert {k[3] for k in keys} == {0, 1, 2} and {k[4] for k in keys} == {0, 1}
    assert len(keys) == len(TABLE4_LINKS) * len({k[2] for k in keys}) * 3 * 2


def test_the_worlds_run_the_environment_seeds_with_one_controller_seed():
    budget = budget_from(parse_args(["worlds", "--seeds", "5", "--env-seeds", "2"]))
    episodes = sweep_episodes("worlds", budget)
    assert {s.scenario for s in episodes} == set(WORLDS)
    assert {s.env_seed for s in episodes} == {0, 1} and {s.seed for s in episodes} == {0}


def test_an_option_below_one_is_a_one_line_error_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "runs"
    with pytest.raises(SystemExit) as exit:
        main(["table4", "--env-seeds", "0", "--out", str(out)])
    assert exit.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == "python -m scenarios.reproduce: error: argument --env-seeds: must be >= 1, got 0"
    assert not out.exists()


def test_an_out_folder_where_no_file_can_go_is_a_one_line_error(tmp_path, capsys):
    (tmp_path / "taken").write_text("")
    for out, why in [(tmp_path / "taken" / "runs", "taken is not a folder"), ("/proc/ncedf-runs", "/proc takes no")]:
        assert main(["table4", "--out", str(out)]) == 2  # /proc takes no new file, even as root
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: cannot write recordings to") and why in err[0]
