#!/usr/bin/env bash
# Installs what the Cortex-M4F image needs, only what is missing (idempotent): QEMU's system
# emulator for Arm (Debian package qemu-system-arm, which carries mps2-an386), the
# thumbv7em-none-eabihf Rust target and llvm-tools (llvm-size for the footprint). No C
# toolchain: the image links with rust-lld.
set -euo pipefail

if ! command -v qemu-system-arm >/dev/null 2>&1; then
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
    start=$(date +%s)
    # --no-install-recommends keeps it to the emulator (no GUI, firmware blobs of other boards).
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends qemu-system-arm >/dev/null
    echo "setup-qemu: installed qemu-system-arm in $(($(date +%s) - start)) s"
fi

rustup target list --installed | grep -qx thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf
rustup component list --installed | grep -q '^llvm-tools' || rustup component add llvm-tools

qemu-system-arm --version | head -n 1
