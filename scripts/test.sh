#!/usr/bin/env bash
# The project's test command (README): checks formatting, lints (the onboard crate's
# panic-freedom lints included) and tests, first of everything that needs no PyTorch, then
# installs PyTorch and does the same for the learning stack; the Cortex-M4F build and QEMU run;
# the C interface hosted by C programs on the host and on the Cortex-M4F; the dataset array and a
# relabelling round's array on a single-node Slurm cluster; the Python package and its tests; the
# fuzzer of the blob loaders and the C interface.
set -euo pipefail
cd "$(dirname "$0")/.."

# Each step's header says when it starts, in seconds since the command began: the CI budget is
# 90 minutes on 2 cores, and these are where it goes.
step() { printf '\n==> [%d s] %s\n' "$SECONDS" "$*"; }

step "toolchain: rustfmt, clippy, thumbv7em-none-eabihf"
rustup component add rustfmt clippy >/dev/null 2>&1 || true
rustup target add thumbv7em-none-eabihf

step "cargo fmt --check"
cargo fmt --all -- --check

# Everything but the learning stack builds and passes its tests with no PyTorch on the machine:
# on a fresh clone this runs before scripts/setup-torch.sh has installed anything.
torch_free=(-p lowthrust-shared -p lowthrust-onboard -p lowthrust-onboard-c -p lowthrust-ground-core -p lowthrust-firmware-sim -p lowthrust-tests)

step "without PyTorch: clippy (warnings are errors)"
cargo clippy "${torch_free[@]}" --all-targets -- -D warnings
cargo clippy -p lowthrust-ground --no-default-features --all-targets -- -D warnings

step "without PyTorch: tests of the core crates and of the trajectory commands"
cargo test "${torch_free[@]}" --all-targets
cargo test -p lowthrust-ground --no-default-features --all-targets

step "onboard + shared for the Cortex-M4F (no_std, no heap), clippy included"
cargo clippy -p lowthrust-onboard -p lowthrust-shared --target thumbv7em-none-eabihf --release -- -D warnings
cargo build -p lowthrust-onboard -p lowthrust-shared --target thumbv7em-none-eabihf --release
cargo clippy -p lowthrust-firmware-sim --lib --no-default-features --target thumbv7em-none-eabihf --release -- -D warnings
cargo clippy -p lowthrust-onboard-c --lib --target thumbv7em-none-eabihf --release -- -D warnings

step "PyTorch 2.13.0 for tch (project venv, once)"
bash scripts/setup-torch.sh

step "clippy, whole workspace with the learning stack (warnings are errors)"
cargo clippy --workspace --all-targets -- -D warnings

step "tests of the learning stack and the full command line"
cargo test -p lowthrust-learn -p lowthrust-ground --all-targets
cargo test --workspace --doc
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps -p lowthrust-shared -p lowthrust-onboard -p lowthrust-onboard-c -p lowthrust-ground-core -p lowthrust-learn -p lowthrust-firmware-sim

step "Cortex-M4F image under QEMU: commands bit for bit equal to the host SIL, refused blobs fly thrust off"
bash scripts/qemu-sil.sh

step "C interface: a C host program and a C Cortex-M4F image under QEMU command the Rust SIL's bits"
bash scripts/c-sil.sh

step "Slurm: the dataset array on a single-node cluster, cancelled, resumed, merged, equal to a single run; a relabelling round's array equal to the round solved here"
cargo build --release -p lowthrust-ground
bash scripts/slurm-ci.sh

step "Python package: an abi3 wheel built by maturin, installed into the project venv; pytest (Gymnasium checker, bit equality with the Rust environments, a numpy MDP, the solver against the CLI, shipped models, SIL and ONNX, Stable-Baselines3)"
.venv/bin/pip install -q "./python[test,sb3]"
LOWTHRUST_GROUND="$PWD/target/release/ground" .venv/bin/python -m pytest -q python/tests

step "fuzzing the blob loader and the C entry points: 2 million inputs, no crash, no altered blob accepted"
cargo run -q --profile c-release -p lowthrust-onboard-c --example fuzz -- --inputs 2000000
step "done"
