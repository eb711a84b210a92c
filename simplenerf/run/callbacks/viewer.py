"""`fit --viewer true`: the web viewer of the run while it trains, rendering from the latest weights.

The viewer's server and render threads run beside training (global rank 0 only). After each step the callback only
tells the viewer the step (`Viewer.weights_changed`): with nobody connected that is all, so training is not slowed
(docs/viewer.md has the measurement); with a browser connected its view is re-rendered from the latest weights at most
every `refresh_seconds`, in a thread that shares the CPU or GPU with training. A render reads the weights while the
optimiser may be updating them in place: it is a preview, and the next one is of the next weights.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L

from simplenerf.data.scene import SceneDataModule
from simplenerf.method.module import SimpleNeRF
from simplenerf.viewer.server import Viewer, check_port


class TrainingViewer(L.Callback):
    """Opens the viewer when fit starts and closes it when fit ends; prints its URL."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, refresh_seconds: float = 2.0) -> None:
        """
        Args:
            host: address to listen on (0.0.0.0: every interface).
            port: port (0: any free one).
            refresh_seconds: a connected browser's view is re-rendered from new weights at most this often.
        """
        self.host, self.port, self.refresh_seconds = host, port, refresh_seconds
        self.viewer: Viewer | None = None

    def check_inputs(self, subcommand: str) -> None:
        """A taken port stops the run before anything is written (`SimpleNeRFCLI` calls this first)."""
        check_port(self.host, self.port)

    def on_fit_start(self, trainer: L.Trainer, pl_module: SimpleNeRF) -> None:
        if not trainer.is_global_zero:
            return
        data: SceneDataModule = trainer.datamodule
        out = Path(trainer.default_root_dir) / "viewer"
        self.viewer = Viewer(pl_module, data.scene, data.near, out, data.sparse_depth, self.host,
                             self.port, refresh_seconds=self.refresh_seconds)
        self.viewer.step = trainer.global_step
        print(f"viewer: open {self.viewer.url} in a browser to watch the training", flush=True)

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs, batch, batch_idx) -> None:
        if self.viewer is not None:
            self.viewer.weights_changed(trainer.global_step)

    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if self.viewer is not None:
            self.viewer.close()
            self.viewer = None
