"""Quality: what a trained run's pictures and depths are worth beyond the test's scores. The runs themselves come from
sweep files (configs/sweeps/quality_grid.yaml and configs/sweeps/fern_cpu.yaml, `simplenerf sweep`); the scripts
here score their maps: streaks along the image axes (`streak_index.py`), texture printed into depth on the demo's
planes (`texture_in_depth.py`), the same scores on training and test views and how rays spread their weight
(`view_scores.py`), what blur and misplacement alone cost (`blur_calibration.py`), and the README's picture of the
demo (`demo_picture.py`). docs/results.md holds their dated figures.
"""
