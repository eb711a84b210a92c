"""Speed and memory of a configured model (benchmarks/*.py): `measure` (timing training and rendering, counting),
`profile` (one step under torch.profiler), `scripts` (the command lines), `release` (side-by-side tables)."""

from simplenerf.benchmark.measure import *  # noqa: F403
from simplenerf.benchmark.profile import profile_table, profile_training  # noqa: F401
from simplenerf.benchmark.release import release_iterations, side_by_side_table  # noqa: F401
from simplenerf.benchmark.scripts import profile_main, render_main, train_step_main  # noqa: F401
