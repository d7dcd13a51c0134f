"""N-CEDF: neural configuration distance functions and MPPI control for continuum robots."""

from ncedf.xla_flags import cpu_flags

cpu_flags()
