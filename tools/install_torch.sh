#!/usr/bin/env bash
# Installs torch into PYTHON's environment, the build that fits this machine (`make setup`, README "Install"):
#
#   tools/install_torch.sh [--dry-run] [PYTHON]      # PYTHON: default python3; --dry-run: say what, install nothing
#
# 1. PYTHON already imports a torch that satisfies pyproject.toml's requirement (torch>=...): kept, nothing installed
#    (a CUDA torch of another version than the pin included).
# 2. Else, an NVIDIA GPU (`nvidia-smi -L` lists one): torch==PIN from pip's own sources (PyPI's Linux wheel is the
#    CUDA build).
# 3. Else (no NVIDIA GPU): torch==PIN from PyTorch's CPU wheel index (https://download.pytorch.org/whl/cpu), no CUDA
#    libraries; unless pip's configuration already names its package sources (index-url, extra-index-url or
#    find-links in a pip.conf or PIP_* variables, as `pip config list` shows them): then torch==PIN from those, since
#    a command-line --index-url would replace a local mirror or wheel folder (and may not be reachable from there).
# TORCH_BUILD=cpu or cuda forces step 3 (with the CPU index) or step 2; TORCH_PIN (default 2.13.0, the tested
# version) sets PIN. One line says which case applied and why.
set -euo pipefail

DRY_RUN=0 PYTHON=
for arg in "$@"; do
  case $arg in
    --dry-run) DRY_RUN=1 ;;
    -*) echo "install_torch: unknown option $arg (expected --dry-run and a Python)" >&2; exit 2 ;;
    *) PYTHON=$arg ;;
  esac
done
PYTHON=${PYTHON:-python3}
PIN=${TORCH_PIN:-2.13.0}
CPU_INDEX=https://download.pytorch.org/whl/cpu
PYPROJECT="$(dirname "$0")/../pyproject.toml"
case ${TORCH_BUILD:-} in
  "" | cpu | cuda) ;;
  *) echo "install_torch: TORCH_BUILD=$TORCH_BUILD: expected cpu or cuda (or unset: decided by the machine)" >&2
     exit 2 ;;
esac

# 1. torch already there and satisfying pyproject.toml's requirement (packaging's rules; pip vendors packaging).
present=$("$PYTHON" - "$PYPROJECT" 2> /dev/null << 'EOF' || true
import re, sys
try:
    import torch
except Exception:
    sys.exit(0)
try:
    from packaging.specifiers import SpecifierSet
except ImportError:
    from pip._vendor.packaging.specifiers import SpecifierSet
requirement = re.search(r'"torch\s*([^";]*)', open(sys.argv[1]).read()).group(1).replace(" ", "")
build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "CPU"
verdict = "ok" if SpecifierSet(requirement).contains(torch.__version__, prereleases=True) else "old"
print(f"{verdict} torch {torch.__version__} ({build} build; pyproject.toml requires torch{requirement})")
EOF
)
if [ -z "${TORCH_BUILD:-}" ] && [ "${present%% *}" = ok ]; then
  echo "install_torch: keeping the installed ${present#ok }"
  exit 0
fi
[ "${present%% *}" = old ] && echo "install_torch: replacing ${present#old }"

if [ "${TORCH_BUILD:-}" = cuda ]; then
  gpu="TORCH_BUILD=cuda"
elif [ -z "${TORCH_BUILD:-}" ] && command -v nvidia-smi > /dev/null && nvidia-smi -L 2> /dev/null | grep -q '^GPU'; then
  gpu="nvidia-smi lists $(nvidia-smi -L | grep -c '^GPU') GPU(s)"
else
  gpu=
fi
command=("$PYTHON" -m pip install "torch==$PIN")
if [ -n "$gpu" ]; then
  echo "install_torch: torch==$PIN from pip's sources, the CUDA build ($gpu)"
else
  sources=$("$PYTHON" -m pip config list 2> /dev/null | grep -E '^[^=]*\.(index-url|extra-index-url|find-links)=' \
    | tr '\n' ' ' || true)
  if [ -n "$sources" ] && [ "${TORCH_BUILD:-}" != cpu ]; then
    echo "install_torch: torch==$PIN from pip's configured sources (no NVIDIA GPU; pip config: ${sources% }; \
TORCH_BUILD=cpu takes PyTorch's CPU index instead)"
  else
    command+=(--index-url "$CPU_INDEX")
    echo "install_torch: torch==$PIN, the CPU build from $CPU_INDEX (${TORCH_BUILD:+TORCH_BUILD=}${TORCH_BUILD:-no NVIDIA GPU})"
  fi
fi
if [ "$DRY_RUN" = 1 ]; then
  printf '%q ' "${command[@]}" | sed 's/ $/\n/'
else
  "${command[@]}"
fi
