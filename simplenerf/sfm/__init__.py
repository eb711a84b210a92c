"""Structure from motion with pycolmap: sparse depth of posed views (DS-NeRF's prior) and own photos -> a scene.

Without pycolmap installed the package still imports, and `sparse_depth.load_or_compute_sparse_depth` reads results
cached before (a GPU machine given a cache); everything that runs COLMAP needs it."""

import importlib.util as _importlib_util
import signal as _signal


def _import_pycolmap_keeping_signal_handlers() -> None:
    """Imports pycolmap, whose COLMAP installs glog's failure-signal handler at import: SIGTERM then prints a native
    stack dump of ~25 lines and kills the process, bypassing the Python handlers (`simplenerf.run.signals`: one line,
    exit status 143, cleanups run). Python's handlers of SIGTERM and SIGINT as they were before the import are set
    again (glog's stays for crashes: SIGSEGV, SIGABRT, ...)."""
    kept = {signum: _signal.getsignal(signum) for signum in (_signal.SIGTERM, _signal.SIGINT)}
    import pycolmap  # noqa: F401

    for signum, handler in kept.items():
        if handler is not None:
            try:
                _signal.signal(signum, handler)
            except ValueError:  # not the main thread: nothing can be set here
                return


# Asked once, here; `sparse_depth` reads it before a computation that would need pycolmap.
PYCOLMAP_INSTALLED = _importlib_util.find_spec("pycolmap") is not None
if PYCOLMAP_INSTALLED:
    _import_pycolmap_keeping_signal_handlers()
