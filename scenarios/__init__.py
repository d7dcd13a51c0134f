"""Closed-loop scenarios: worlds, their runners, the exact judge, sweeps and the reproduction."""

#: The worlds beyond the paper's: the charging port (the authors' release) and the confined spaces.
WORLDS = ("charging", "window", "cabinet", "pipe", "slot", "pillars")
