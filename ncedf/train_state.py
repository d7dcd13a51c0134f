"""Where a training run stands after an epoch, saved so that a stopped run resumes exactly.

A :class:`TrainState` holds what the next epoch needs: the parameters, the optimizer's state (its
step count drives the learning-rate schedule), the key the next epoch splits, and the history rows so
far. ``ncedf.train.train`` resumes from one and continues with the same floats as a run never stopped.
:func:`save_state` writes one atomically (a file written beside it, then renamed), with a fingerprint
of what produced it; :func:`load_state` reads it back into a template of the same structure, or gives
None where there is none or the fingerprint differs (another run's file is never resumed).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import flax.serialization
import jax.numpy as jnp


class TrainState(NamedTuple):
    """After ``epoch`` epochs: ``params``, ``opt_state``, the PRNG ``key`` of the next epoch and the
    ``history`` rows (a tuple of dicts of floats, one per epoch)."""

    epoch: int
    params: Any
    opt_state: Any
    key: jnp.ndarray
    history: tuple = ()


def save_state(path: str | Path, state: TrainState, fingerprint: str) -> None:
    """Write ``state`` to ``path`` (msgpack) with ``fingerprint``; the old file stays whole until the new
    one is complete."""
    path = Path(path)
    body = {"fingerprint": fingerprint, "epoch": state.epoch, "key": state.key,
            "params": flax.serialization.to_state_dict(state.params),
            "opt_state": flax.serialization.to_state_dict(state.opt_state),
            "history": json.dumps(list(state.history))}
    partial = path.with_name(path.name + ".partial")
    partial.write_bytes(flax.serialization.msgpack_serialize(body))
    os.replace(partial, path)


def load_state(path: str | Path, template: TrainState, fingerprint: str) -> TrainState | None:
    """The state saved at ``path`` in the structure of ``template`` (a fresh run's first state), or None
    where there is no file or it was saved with another fingerprint."""
    path = Path(path)
    if not path.is_file():
        return None
    body = flax.serialization.msgpack_restore(path.read_bytes())
    if body.get("fingerprint") != fingerprint:
        return None
    history = tuple(json.loads(body["history"]))
    return TrainState(int(body["epoch"]), flax.serialization.from_state_dict(template.params, body["params"]),
                      flax.serialization.from_state_dict(template.opt_state, body["opt_state"]),
                      jnp.asarray(body["key"]), history)
