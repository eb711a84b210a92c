"""Every callback a run uses, by what it serves. Configs name them here, e.g.
`class_path: simplenerf.run.callbacks.LossWeightSchedule`.

- the loss (the method's step-dependent weights): `LossWeightSchedule` (training.py)
- watching a run: `TrainingProgressBar`, `ProgressLog`, `RaysPerSecond`, `LearningRates` (training.py)
- nothing lost on a crash: `Checkpointing`, `StopOnNonFiniteLoss` (training.py); `RunRecord` (random state and settings
  in checkpoints: `simplenerf.run.resume`, beside the resume that reads them)
- pictures: `ValidationRenders` (validation frame and reliability masks), `TrainingVideo` (video at the end of fit)
  (pictures.py; the drawing is `simplenerf.viz`'s)
- the web viewer during training: `TrainingViewer` (viewer.py, `fit --viewer true`; imported on demand: viser is an
  optional dependency)
- the evaluation protocol at `test`: `Evaluator` (`simplenerf.evaluation.evaluator`, the protocol it implements)
"""

from simplenerf.evaluation.evaluator import Evaluator
from simplenerf.run.callbacks.pictures import TrainingVideo, ValidationRenders
from simplenerf.run.callbacks.training import (
    Checkpointing,
    LearningRates,
    LossWeightSchedule,
    ProgressLog,
    RaysPerSecond,
    StopOnNonFiniteLoss,
    TrainingProgressBar,
    untrained_augmentations,
)
from simplenerf.run.resume import RunRecord

__all__ = [
    "Checkpointing",
    "Evaluator",
    "LearningRates",
    "LossWeightSchedule",
    "ProgressLog",
    "RaysPerSecond",
    "RunRecord",
    "StopOnNonFiniteLoss",
    "TrainingProgressBar",
    "TrainingVideo",
    "ValidationRenders",
    "untrained_augmentations",
]
