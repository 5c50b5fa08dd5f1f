#!/usr/bin/env bash
# The Cortex-M4F SIL check: for each weight blob, build the firmware image of the blob's problem
# with the blob in flash (firmware_sim/m4; the `rendezvous` feature for a rendezvous blob,
# `spatial` for a three-dimensional one), fly the trace's flights of that problem on QEMU's
# mps2-an386, fly the same on the host (firmware_sim's sil_trace, `--rendezvous`, `--spatial`
# likewise), and require the two traces to be identical (every command and state as f64 bits).
# Prints instructions per inference, flash/RAM footprint, stack peak.
#
#   scripts/qemu-sil.sh                 # seeded random f32 + int8 blobs of the four problems (random_blob)
#   scripts/qemu-sil.sh A.blob B.blob   # these blobs (e.g. ground model export's transfer-*.blob, rendezvous-*.blob)
#
# Either way it also checks refusal: for each planar problem flown, its last blob altered (one
# byte flipped), truncated and given the next format version, and a blob of the other problem;
# for each problem, a blob of the other dimension (planar for a 3D image, 3D for the planar
# transfer image). Each must be refused by that problem's image with the typed error, flown with
# thrust off (every throttle bit zero), exit 0, and match the host.
# Exit status: non-zero on any trace difference, failed run or failed check. The
# instruction and footprint targets are reported (met / MISSED), not enforced.
# QEMU_SIL_PROFILE=1 also times each stage of the forward pass (a second image per good blob,
# built with the m4 crate's `profile` feature, which the footprint does not include).
# Outputs: target/qemu-sil/ (traces, images, diffs).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)

M4=firmware_sim/m4
# The image's own target folder, whatever CARGO_TARGET_DIR says for the workspace.
M4_TARGET="$PWD/$M4/target"
OUT=target/qemu-sil
HOST_BIN="${CARGO_TARGET_DIR:-target}/release"
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

# Instruction and footprint targets of the Cortex-M4 image (the transfer policy's, applied to the
# others too: their first layers have 22, 15 or 30 inputs instead of 10, the 3D last layers 4
# outputs instead of 3).
F32_MAX_INSN=160000
INT8_MAX_INSN=100000
FLASH_MAX=$((256 * 1024))
RAM_MAX=$((64 * 1024))

step() { printf '\n==> %s\n' "$*"; }
die() {
    echo "qemu-sil: FAIL: $*" >&2
    exit 1
}

llvm_size=$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/llvm-size 2>/dev/null | head -n 1 || true)
if ! command -v qemu-system-arm >/dev/null 2>&1 || [ -z "$llvm_size" ] \
    || ! rustup target list --installed | grep -qx thumbv7em-none-eabihf; then
    bash scripts/setup-qemu.sh
    llvm_size=$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/llvm-size | head -n 1)
fi

# The image and the host must run the same code: every crate the image's own lockfile shares
# with the workspace's must be at a version the workspace uses (libm above all).
step "image dependencies match the workspace's"
versions() { awk '/^name = /{n=$3} /^version = /{print n, $3}' "$1" | tr -d '"' | sort -u; }
mismatch=$(awk 'NR == FNR {have[$1] = have[$1] " " $2 " "; next}
                ($1 in have) && index(have[$1], " " $2 " ") == 0 {printf "%s %s; ", $1, $2}' \
    <(versions Cargo.lock) <(versions "$M4/Cargo.lock"))
[ -z "$mismatch" ] || die "firmware_sim/m4/Cargo.lock has versions the workspace does not: $mismatch"
echo "shared crates at the workspace's versions"

step "host tools (release): random_blob, sil_trace"
nice cargo build --release -q -p lowthrust-firmware-sim --bin random_blob --bin sil_trace

# random_blob's four problems: its flags and blob name prefixes.
random_blobs() {
    local out=$1
    "$HOST_BIN/random_blob" --seed 1 --out "$out" >/dev/null
    "$HOST_BIN/random_blob" --seed 1 --out "$out" --rendezvous >/dev/null
    "$HOST_BIN/random_blob" --seed 1 --out "$out" --spatial >/dev/null
    "$HOST_BIN/random_blob" --seed 1 --out "$out" --rendezvous --spatial >/dev/null
}
blobs=("$@")
if [ ${#blobs[@]} -eq 0 ]; then
    random_blobs "$OUT/blobs"
    blobs=()
    for p in transfer rendezvous transfer3 rendezvous3; do
        blobs+=("$OUT/blobs/$p-f32.blob" "$OUT/blobs/$p-int8.blob")
    done
fi
for b in "${blobs[@]}"; do [ -f "$b" ] || die "no blob $b"; done

# The problem a blob is for: the second payload byte (offset 11, after magic, version, length
# and NetworkBlob::kind) is the postcard index of NetworkBlob::features, the FeatureLayout: 0
# transfer, 1 rendezvous, 2 and 3 the same in three dimensions (shared/src/blob.rs). A misread
# layout would show as a good blob refused.
blob_problem() {
    [ "$(head -c 4 "$1")" = LTGB ] || die "$1 is not a weight blob (no LTGB magic)"
    case $(od -An -tu1 -j 11 -N1 "$1" | tr -d ' ') in
        0) echo transfer ;;
        1) echo rendezvous ;;
        2) echo transfer3 ;;
        3) echo rendezvous3 ;;
        *) die "$1: unknown problem" ;;
    esac
}
problems=()
declare -A last=()
for b in "${blobs[@]}"; do
    p=$(blob_problem "$b")
    [ -n "${last[$p]:-}" ] || problems+=("$p")
    last[$p]=$b
done

# Refusal cases of each problem flown, derived from its last blob; the other problem's and other
# dimension's blobs are seeded random ones.
neg="$OUT/refused"
mkdir -p "$neg"
random_blobs "$neg"
# spoil PREFIX BLOB: PREFIX{altered,truncated,version}.blob
spoil() {
    local prefix=$1 blob=$2 size offset byte version
    size=$(stat -c %s "$blob")
    cp "$blob" "$neg/${prefix}altered.blob"
    offset=$((size / 2))
    byte=$(od -An -tu1 -j "$offset" -N1 "$blob" | tr -d ' ')
    # shellcheck disable=SC2059 # the format is the octal escape of the flipped byte
    printf "$(printf '\\%03o' $((byte ^ 0xff)))" | dd of="$neg/${prefix}altered.blob" bs=1 seek="$offset" conv=notrunc status=none
    head -c $((size - 1000)) "$blob" >"$neg/${prefix}truncated.blob"
    cp "$blob" "$neg/${prefix}version.blob"
    version=$(od -An -tu2 -j 4 -N2 --endian=little "$blob" | tr -d ' ')
    # shellcheck disable=SC2059 # little-endian u16 of the next format version, as octal escapes
    printf "$(printf '\\%03o\\%03o' $(((version + 1) & 0xff)) $(((version + 1) >> 8)))" |
        dd of="$neg/${prefix}version.blob" bs=1 seek=4 conv=notrunc status=none
}
for p in "${problems[@]}"; do
    case $p in
        transfer) spoil "" "${last[$p]}" ;;
        rendezvous) spoil "$p-" "${last[$p]}" ;;
    esac
done

step "clippy and rustfmt for the image crate (excluded from the workspace), transfer and rendezvous images"
any_blob=$(realpath "${blobs[0]}")
(cd "$M4" && CARGO_TARGET_DIR="$M4_TARGET" LOWTHRUST_BLOB="$any_blob" nice cargo clippy --release -q -- -D warnings)
(cd "$M4" && CARGO_TARGET_DIR="$M4_TARGET" LOWTHRUST_BLOB="$any_blob" nice cargo clippy --release -q --features rendezvous,profile -- -D warnings)
(cd "$M4" && CARGO_TARGET_DIR="$M4_TARGET" LOWTHRUST_BLOB="$any_blob" nice cargo clippy --release -q --features spatial,profile -- -D warnings)
(cd "$M4" && cargo fmt --check)

summary=()
failed=0

# run_case NAME BLOB ok|refused transfer|rendezvous|transfer3|rendezvous3 (the image's problem)
run_case() {
    local name=$1 blob=$2 expect=$3 problem=$4
    local qemu="$OUT/$name.qemu.txt" host="$OUT/$name.host.txt"
    # The image's features and its host twin's flags.
    local features=() twin=() profile=profile
    case $problem in
        rendezvous) twin=(--rendezvous) profile=profile,rendezvous ;;
        transfer3) twin=(--spatial) profile=profile,spatial ;;
        rendezvous3) twin=(--rendezvous --spatial) profile=profile,rendezvous,spatial ;;
    esac
    [ "$problem" = transfer ] || features=(--features "${profile#profile,}")
    step "$name: $(basename "$blob") ($(stat -c %s "$blob") bytes), $problem image, expected: $expect"
    (cd "$M4" && CARGO_TARGET_DIR="$M4_TARGET" LOWTHRUST_BLOB="$(realpath "$blob")" nice cargo build --release -q "${features[@]}")
    cp "$M4_TARGET/thumbv7em-none-eabihf/release/lowthrust-m4" "$OUT/$name.elf"
    # The runner (QEMU and its flags) is the one in firmware_sim/m4/.cargo/config.toml.
    local rc=0
    (cd "$M4" && CARGO_TARGET_DIR="$M4_TARGET" LOWTHRUST_BLOB="$(realpath "$blob")" timeout 300 cargo run --release -q "${features[@]}") \
        >"$qemu" 2>"$OUT/$name.qemu.err" || rc=$?
    if [ $rc -ne 0 ]; then
        cat "$OUT/$name.qemu.err" >&2
        echo "image exited with status $rc" >&2
        failed=1
        return
    fi
    "$HOST_BIN/sil_trace" "$blob" "${twin[@]}" --latency >"$host"
    if diff <(grep -v '^#' "$qemu") <(grep -v '^#' "$host") >"$OUT/$name.diff"; then
        echo "traces identical: $(grep -vc '^#' "$qemu") lines (commands and states as f64 bits)"
    else
        head -n 20 "$OUT/$name.diff" >&2
        echo "traces differ: $OUT/$name.diff" >&2
        failed=1
    fi
    head -n 1 "$qemu"
    grep -h '^#' "$qemu" "$host" | sed 's/^# /  /'
    grep '^end' "$qemu" | sed 's/^/  /'
    if [ "$expect" = refused ]; then
        grep -q '^blob refused: ' "$qemu" || {
            echo "the image did not refuse the blob" >&2
            failed=1
        }
        # Throttle of the command and of what was applied: the first value after each.
        if ! awk '$1 == "step" { for (i = 1; i < NF; i++) if (($i == "cmd" || $i == "applied") && $(i + 1) != "0000000000000000") bad = 1 }
                  END { exit bad }' "$qemu"; then
            echo "a refused blob flew with thrust on" >&2
            failed=1
        fi
        summary+=("$(printf '%-22s refused, thrust off: %s' "$name" "$(head -n 1 "$qemu" | cut -c 15-)")")
        return
    fi
    grep -q '^blob \(f32\|int8\) ' "$qemu" || {
        echo "the image refused a good blob" >&2
        failed=1
        return
    }
    local quant insn peak flash ram
    quant=$(awk 'NR == 1 {print $2}' "$qemu")
    insn=$(sed -n 's/.*instructions per inference over.*: median \([0-9]*\) .*/\1/p' "$qemu")
    peak=$(sed -n 's/.*high-water mark \([0-9]*\) bytes in flight.*/\1/p' "$qemu")
    # Flash: what is loaded (vector table, code, constants including the blob, .data's image);
    # RAM: .data + .bss + .uninit, plus the stack's measured peak.
    read -r flash ram < <("$llvm_size" -A "$OUT/$name.elf" |
        awk '$1 ~ /^\.(vector_table|text|rodata)$/ {f += $2} $1 == ".data" {f += $2; r += $2}
             $1 ~ /^\.(bss|uninit)$/ {r += $2} END {print f, r}')
    if [ "${QEMU_SIL_PROFILE:-0}" = 1 ]; then
        (cd "$M4" && CARGO_TARGET_DIR="$M4_TARGET" LOWTHRUST_BLOB="$(realpath "$blob")" timeout 300 nice cargo run --release -q --features "$profile") \
            2>/dev/null | grep '^# profile' | sed 's/^# /  /' || true
    fi
    local limit=$F32_MAX_INSN verdict
    [ "$quant" = int8 ] && limit=$INT8_MAX_INSN
    verdict=$([ "$insn" -le "$limit" ] && echo met || echo MISSED)
    local fit=""
    if [ "$quant" = int8 ]; then
        fit=$([ "$flash" -le $FLASH_MAX ] && [ $((ram + peak)) -le $RAM_MAX ] && echo "fits 256 KiB/64 KiB" || echo "MISSES 256 KiB/64 KiB")
    fi
    summary+=("$(printf '%-22s %-4s %7d instructions/inference (target %d: %s); flash %d B (%.1f KiB); RAM %d B static + %d B stack peak %s' \
        "$name" "$quant" "$insn" "$limit" "$verdict" "$flash" "$(awk "BEGIN {print $flash / 1024}")" "$ram" "$peak" "$fit")")
}

for b in "${blobs[@]}"; do
    run_case "$(basename "$b" .blob)" "$b" ok "$(blob_problem "$b")"
done
for p in "${problems[@]}"; do
    case $p in
        transfer | rendezvous)
            prefix=""
            [ "$p" = rendezvous ] && prefix="$p-"
            for n in altered truncated version; do
                run_case "$prefix$n" "$neg/$prefix$n.blob" refused "$p"
            done
            ;;
    esac
    # A blob of the other problem, and of the other dimension.
    case $p in
        transfer)
            run_case wrong-kind "$neg/rendezvous-int8.blob" refused transfer
            run_case wrong-dimension "$neg/transfer3-int8.blob" refused transfer
            ;;
        rendezvous) run_case rendezvous-wrong-kind "$neg/transfer-int8.blob" refused rendezvous ;;
        transfer3) run_case transfer3-wrong-dimension "$neg/transfer-int8.blob" refused transfer3 ;;
        rendezvous3) run_case rendezvous3-wrong-dimension "$neg/rendezvous-int8.blob" refused rendezvous3 ;;
    esac
done

step "summary ($(($(date +%s) - start)) s)"
printf '%s\n' "${summary[@]}"
[ $failed -eq 0 ] || die "see above"
echo "qemu-sil: host and Cortex-M4 traces identical for every blob"
