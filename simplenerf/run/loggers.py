"""Weights & Biases logging that works on a machine with no network or account: offline unless credentials exist."""

from __future__ import annotations

import json
import netrc
import os
import re
import struct
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
        save_dir: str | None = None,
        offline: bool | None = None,
        log_model: bool = False,
        group: str | None = None,
        tags: list[str] | None = None,
        id: str | None = None,
    ) -> None:
        """
        Args:
            project: W&B project.
            name: run name shown in W&B.
            save_dir: folder for the local W&B files; null: the run folder (`trainer.default_root_dir`), which the
                CLI sets (`use_run_folder`).
            offline: force offline/online; None: online only if credentials exist or WANDB_MODE says so.
            log_model: upload checkpoints as W&B artifacts.
            group: W&B group (a sweep's runs share one, `simplenerf.experiments`).
            tags: W&B tags (a sweep tags each run with its scene, views, model and seed).
            id: W&B run id: a run started again with the same id continues that W&B run (a resumed or requeued
                fit of a sweep); None: a new id each start.
        """
        if offline is None:
            offline = os.environ.get("WANDB_MODE", "") in ("offline", "dryrun", "disabled") or (
                os.environ.get("WANDB_MODE") != "online" and not wandb_credentials_available()
            )
        super().__init__(
            project=project, name=name, save_dir=save_dir, offline=offline, log_model=log_model,
            settings={"silent": True}, id=id,
            **{k: v for k, v in (("group", group), ("tags", tags)) if v is not None},
        )
        # Lightning passes anonymous=None, which W&B answers with a deprecation warning at every start.
        self._wandb_init.pop("anonymous", None)

    def use_run_folder(self, folder: str | Path) -> None:
        """Keeps the W&B files in the run folder `folder` unless `save_dir` named another (the CLI calls this once the
        trainer exists, so a run's folder is one setting, `trainer.default_root_dir`)."""
        if self._save_dir is None:
            self._save_dir = os.fspath(folder)
            self._wandb_init["dir"] = self._save_dir

    @property
    def experiment(self):
        """The W&B run, started on first use; its folder is created only then."""
        new = self._experiment is None
        if new and self._save_dir is not None:
            Path(self._save_dir).mkdir(parents=True, exist_ok=True)
        run = super().experiment
        if new and self._experiment is not None:  # started here, on global rank 0
            # W&B's run objects differ by mode (a disabled run is a stub without these attributes).
            if getattr(run, "offline", False):
                folder = run.settings.sync_dir
                print(f"W&B: offline run in {folder} (upload it later with `wandb sync {folder}`)", flush=True)
            elif not getattr(run, "disabled", False):
                print(f"W&B: {run.url}", flush=True)
        return run


def logged_history(save_dir: str | Path) -> list[dict[str, object]]:
    """The rows a run logged to W&B (every `log`/`log_dict` call, e.g. the losses and mask fractions over training),
    read back from its local `<save_dir>/wandb/*run-*/run-*.wandb` files (offline or synced runs; a resumed fit's
    runs in the order they were started), without network or account. Each row maps the logged names to values.

    The file is W&B's transaction log: the LevelDB log format (32 KiB blocks of records, each with a 7-byte header:
    checksum, length, type FULL / FIRST / MIDDLE / LAST) after a 7-byte file header, holding `Record` protobufs.
    """
    from wandb.proto import wandb_internal_pb2

    files = sorted(Path(save_dir).glob("wandb/*run-*/run-*.wandb"), key=_started)
    if not files:
        raise FileNotFoundError(f"no W&B run in {Path(save_dir) / 'wandb'} (expected */run-*.wandb)")
    rows = []
    for file in files:
        for data in _log_records(file):
            record = wandb_internal_pb2.Record()
            record.ParseFromString(data)
            if record.WhichOneof("record_type") == "history":
                rows.append({item.key or "/".join(item.nested_key): json.loads(item.value_json)
                             for item in record.history.item})
    return rows


def _started(file: Path) -> str:
    """A run folder's start time, `[offline-]run-<YYYYmmdd_HHMMSS>-<id>` (its name if it has none)."""
    match = re.search(r"run-(\d{8}_\d{6})", file.parent.name)
    return match.group(1) if match else file.parent.name


def _log_records(file: Path, block: int = 32768):
    data = file.read_bytes()
    if data[:4] != b":W&B":
        raise ValueError(f"{file} is not a W&B run log (it starts {data[:4]!r}, expected b':W&B')")
    pos, pending = 7, b""
    while pos + 7 <= len(data):
        left = block - pos % block
        if left < 7:  # a block's tail too short for a header is padding
            pos += left
            continue
        _, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        if kind == 0:  # zero padding (a preallocated or unfinished block)
            pos += left
            continue
        chunk, pos = data[pos + 7 : pos + 7 + length], pos + 7 + length
        if kind == 1:
            yield chunk
        elif kind == 2:
            pending = chunk
        elif kind == 3:
            pending += chunk
        elif kind == 4:
            yield pending + chunk
            pending = b""
