#!/usr/bin/env bash
# The project's test command (README): installs what it needs, then checks formatting, lints
# (the onboard crate's panic-freedom lints included), the Cortex-M4F build, and runs all tests.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }

step "PyTorch 2.13.0 for tch (project venv, once)"
bash scripts/setup-torch.sh

step "toolchain: rustfmt, clippy, thumbv7em-none-eabihf"
rustup component add rustfmt clippy >/dev/null 2>&1 || true
rustup target add thumbv7em-none-eabihf

step "cargo fmt --check"
cargo fmt --all -- --check

step "clippy (host, all targets, warnings are errors)"
cargo clippy --workspace --all-targets -- -D warnings

step "onboard + shared for the Cortex-M4F (no_std, no heap), clippy included"
cargo clippy -p lowthrust-onboard -p lowthrust-shared --target thumbv7em-none-eabihf --release -- -D warnings
cargo build -p lowthrust-onboard -p lowthrust-shared --target thumbv7em-none-eabihf --release
cargo clippy -p lowthrust-firmware-sim --lib --no-default-features --target thumbv7em-none-eabihf --release -- -D warnings

step "tests"
cargo test --workspace --all-targets
cargo test --workspace --doc

step "Cortex-M4F image under QEMU: commands bit for bit equal to the host SIL, refused blobs fly thrust off"
bash scripts/qemu-sil.sh
