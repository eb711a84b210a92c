"""tests/preloaded_cli.py gives what a fresh `python -m simplenerf` gives: exit status, stdout, stderr, in the call's
own working directory."""

import subprocess
import sys

from tests import preloaded_cli
from tests.conftest import REPO


def test_a_call_through_the_server_matches_a_fresh_interpreter(tmp_path):
    (tmp_path / "here.yaml").write_text("model: [unclosed\n")  # found only from tmp_path, and not valid YAML
    calls = [(REPO, ["--version"]), (REPO, ["fti", "--config", "x.yaml"]), (tmp_path, ["fit", "--config", "here.yaml"])]
    for cwd, args in calls:
        fresh = subprocess.run([sys.executable, "-m", "simplenerf", *args], cwd=cwd, capture_output=True, text=True,
                               timeout=120)
        served = preloaded_cli.run(args, cwd=cwd)
        assert (served.returncode, served.stdout, served.stderr) == (fresh.returncode, fresh.stdout, fresh.stderr)
        assert served.returncode == (0 if args == ["--version"] else 2), served.stderr
    assert "did you mean fit?" in preloaded_cli.run(["fti"], cwd=REPO).stderr
