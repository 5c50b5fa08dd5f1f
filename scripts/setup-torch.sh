#!/usr/bin/env bash
# Installs PyTorch 2.13.0 (the version tch 0.26 binds) into the project venv, once, and links
# .venv/torch to it; .cargo/config.toml points LIBTORCH there. Idempotent and quiet when done.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
if ! .venv/bin/python -c 'import torch, sys; sys.exit(torch.__version__.split("+")[0] != "2.13.0")' 2>/dev/null; then
    echo "==> installing torch==2.13.0 into .venv (about 75 s and 4.7 GB, once)"
    .venv/bin/pip install --quiet --disable-pip-version-check torch==2.13.0
fi
torch_dir=$(.venv/bin/python -c 'import torch, os; print(os.path.dirname(torch.__file__))' 2>/dev/null)
ln -sfn "$torch_dir" .venv/torch
