"""`python -m simplenerf ...` for the tests, without paying the interpreter's imports at every call.

A start of the command line costs about 6.5 s before any work on the 2-core CPU (importing Lightning, which imports
torch._dynamo, torchmetrics and scipy; docs/testing.md), and the suite starts it a few hundred times. `run` asks a
server process, started once per test process, that has imported the command line's modules and runs nothing else
(no training, no rendering; the imports start three native threads there, which a fork does not copy into the
child, as POSIX has it: only the forking thread goes on): it forks, and the child sets up the call as
`subprocess.run` would (working directory, environment, stdout and stderr to files, stdin from /dev/null, argv) and
runs `simplenerf`'s `__main__` with `runpy`, as `python -m simplenerf` does, then exits the way an interpreter exits
(atexit handlers, exit status, a traceback and status 1 on an uncaught exception). What differs from a fresh
interpreter: the modules are imported before the call's environment is set, so a variable read at import time would
be the server's (the package reads its variables when a command runs; tests/test_layout.py and tests/run/test_faults.py
keep real processes where the start itself is what is tested), and library warnings printed at import time are not
in the child's stderr.

`SIMPLENERF_TEST_FORK=0` (or a platform without `os.fork`) runs every call as a fresh process instead.
"""

from __future__ import annotations

import atexit
import json
import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

# The server: imports the command line, then serves one call at a time (a JSON line in, a JSON line out). Its own
# stdout is kept for the replies; anything a library prints goes to its stderr.
SERVER = r"""
import json, os, sys, time
replies = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)
import simplenerf.commands, simplenerf.run.cli  # what every Lightning verb imports first
replies.write("ready\n"); replies.flush()
for line in sys.stdin:
    call = json.loads(line)
    sys.stdout.flush(); sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        break
    deadline = time.monotonic() + call["timeout"]
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            code = -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)
            replies.write(json.dumps({"returncode": code}) + "\n"); replies.flush()
            break
        if time.monotonic() > deadline:
            os.kill(pid, 9); os.waitpid(pid, 0)
            replies.write(json.dumps({"timeout": True}) + "\n"); replies.flush()
            break
        time.sleep(0.005)
else:
    sys.exit(0)
# The child: the call, as subprocess.run would start it.
replies.close()
os.chdir(call["cwd"])
os.environ.clear(); os.environ.update(call["env"])
null = os.open(os.devnull, os.O_RDONLY); os.dup2(null, 0); os.close(null)
for fd, path in ((1, call["stdout"]), (2, call["stderr"])):
    handle = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644); os.dup2(handle, fd); os.close(handle)
sys.path[0] = os.getcwd()  # as -m sets it (the server, started with -c, has "")
sys.argv = ["-m", *call["args"]]
import runpy
runpy.run_module("simplenerf", run_name="__main__", alter_sys=True)
"""


class _Server:
    def __init__(self, cwd: Path) -> None:
        self.lock = threading.Lock()
        self.process = subprocess.Popen([sys.executable, "-c", SERVER], cwd=cwd, stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        if self.process.stdout.readline().strip() != "ready":
            raise RuntimeError(f"the command line's server did not start (exit {self.process.wait()})")
        atexit.register(self.close)

    def call(self, args: list[str], cwd: Path, env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
        with self.lock, tempfile.TemporaryDirectory(prefix="simplenerf-cli-") as tmp:
            out, err = Path(tmp) / "stdout", Path(tmp) / "stderr"
            request = {"args": args, "cwd": str(cwd), "env": env, "stdout": str(out), "stderr": str(err),
                       "timeout": timeout}
            self.process.stdin.write(json.dumps(request) + "\n")
            self.process.stdin.flush()
            line = self.process.stdout.readline()
            if not line:
                raise RuntimeError(f"the command line's server exited ({self.process.wait()})")
            reply = json.loads(line)
            command = [sys.executable, "-m", "simplenerf", *args]
            stdout, stderr = out.read_text(errors="replace"), err.read_text(errors="replace")
            if reply.get("timeout"):
                raise subprocess.TimeoutExpired(command, timeout, stdout, stderr)
            return subprocess.CompletedProcess(command, reply["returncode"], stdout, stderr)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=30)


_server: _Server | None = None


def run(args: list[str], cwd: Path, env: dict[str, str] | None = None,
        timeout: float = 600) -> subprocess.CompletedProcess:
    """`subprocess.run([sys.executable, "-m", "simplenerf", *args], cwd=cwd, env=env, capture_output=True,
    text=True, timeout=timeout)`, through the server where forking is available (env None: this process's)."""
    env = dict(os.environ if env is None else env)
    if os.environ.get("SIMPLENERF_TEST_FORK", "1") == "0" or not hasattr(os, "fork"):
        return subprocess.run([sys.executable, "-m", "simplenerf", *args], cwd=cwd, env=env, capture_output=True,
                              text=True, timeout=timeout)
    global _server
    if _server is None or _server.process.poll() is not None:
        _server = _Server(Path(__file__).resolve().parents[1])
    return _server.call([str(a) for a in args], cwd, env, timeout)
