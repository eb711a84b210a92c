"""Speed and memory: seconds per training step and peak memory of a config (`training_step.py`, the measurement behind
`simplenerf benchmark`), full-frame rendering (`render.py`), one profiled step (`profile_step.py`), the matrix products'
ceiling (`gemm_rate.py`), candidate fields' cost per sample (`grid_cost.py`), a plane's sampling on one core or all
(`grid_sample_threads.py`), the authors' release beside ours in one sitting (`side_by_side.sh`,
`render_side_by_side.sh`, `release_render.py`, tables by `summarize.py`) and the paper's path on one GPU (`gpu.sh`, its
figures by `gpu_report.py`). Each measurement prints one JSON line; run one per process, since peak memory is per
process. benchmarks/README.md says what is counted.
"""
