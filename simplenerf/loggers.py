"""Weights & Biases logging that works on a machine with no network or account: offline unless credentials exist."""

from __future__ import annotations

import netrc
import os
from pathlib import Path

from lightning.pytorch.loggers import WandbLogger as _LightningWandbLogger


def wandb_credentials_available() -> bool:
    """True if wandb could log online: an API key in the environment or a netrc entry (what `wandb login` writes)."""
    if os.environ.get("WANDB_API_KEY"):
        return True
    path = Path(os.environ.get("NETRC", Path.home() / ".netrc"))
    try:
        return path.is_file() and any("wandb" in host for host in netrc.netrc(path).hosts)
    except (OSError, netrc.NetrcParseError):
        return False


class WandbLogger(_LightningWandbLogger):
    """Lightning's W&B logger, offline (no network, no prompt) when no credentials are found.

    Offline runs are written under `<save_dir>/wandb/` and can be uploaded later with `wandb sync`. Nothing is created
    on disk until the run starts logging (after the CLI's input checks), and W&B's console output is replaced by one
    line saying where the run is (its URL, or the offline folder and how to upload it).
    """

    def __init__(
        self,
        project: str = "simplenerf",
        name: str | None = None,
        save_dir: str = "runs",
        offline: bool | None = None,
        log_model: bool = False,
    ) -> None:
        """
        Args:
            project: W&B project.
            name: run name shown in W&B.
            save_dir: folder for the local W&B files.
            offline: force offline/online; None: online only if credentials exist or WANDB_MODE says so.
            log_model: upload checkpoints as W&B artifacts.
        """
        if offline is None:
            offline = os.environ.get("WANDB_MODE", "") in ("offline", "dryrun", "disabled") or (
                os.environ.get("WANDB_MODE") != "online" and not wandb_credentials_available()
            )
        super().__init__(
            project=project, name=name, save_dir=save_dir, offline=offline, log_model=log_model,
            settings={"silent": True},
        )
        # Lightning passes anonymous=None, which W&B answers with a deprecation warning at every start.
        self._wandb_init.pop("anonymous", None)

    @property
    def experiment(self):
        """The W&B run, started on first use; its folder is created only then."""
        new = self._experiment is None
        if new and self._save_dir is not None:
            Path(self._save_dir).mkdir(parents=True, exist_ok=True)
        run = super().experiment
        if new and self._experiment is not None:  # started here, on global rank 0
            if getattr(run, "offline", False):
                folder = run.settings.sync_dir
                print(f"W&B: offline run in {folder} (upload it later with `wandb sync {folder}`)", flush=True)
            elif not getattr(run, "disabled", False):
                print(f"W&B: {run.url}", flush=True)
        return run
