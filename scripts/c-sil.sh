#!/usr/bin/env bash
# The C interface's check: the controller hosted by C programs, through liblowthrust.a and
# include/lowthrust.h, must command the same bits as the Rust SIL.
#
# For each weight blob, onboard/c's guidance_calls example records the guidance calls of the
# Rust SIL's trace flights (firmware_sim's sil_trace: same scenarios, dispersions, seeds; the
# navigation state each step was given) plus inputs guidance must refuse, then the onboard aids
# (rollout lookahead, terminal targeting) on some of those steps and on the refused inputs, and
# writes what each call must return, the aids' reports included. The four problems are covered: transfer and rendezvous in the plane, and in
# three dimensions on the inclined trace flights (lt_transfer3_step, lt_rendezvous3_step, RTN
# commands). Then
#   1. the host C program (onboard/c/examples/fly.c, gcc) flies every call and its output must
#      equal the expected one, byte for byte (commands as f64 bits, refusal codes);
#   2. its flight commands must equal the `cmd` bits of sil_trace's own trace of the blob;
#   3. a C firmware image (onboard/c/examples/m4, arm-none-eabi-gcc, liblowthrust.a for
#      thumbv7em-none-eabihf) flies the same calls on QEMU's mps2-an386 with the output equal
#      too; it must contain no panic path, and the int8 image must fit 256 KiB flash / 64 KiB RAM.
# Blobs: seeded random f32 and int8 blobs of the four problems (random_blob, with --spatial for
# three dimensions); refused: the int8 transfer blob with one byte flipped, truncated, with the
# next format version, a rendezvous blob loaded as transfer, a planar blob loaded as a transfer
# in three dimensions and a three-dimensional one as a planar transfer (each must be refused with
# its code and fly thrust off). The host program must also refuse a calls file of a format or
# problem it does not know.
# Exit status: non-zero on any difference or failed check. Outputs: target/c-sil/.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)

BIN="${CARGO_TARGET_DIR:-target}"
OUT=target/c-sil
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
EXAMPLES=onboard/c/examples
M4="$EXAMPLES/m4"
FLASH_MAX=$((256 * 1024))
RAM_MAX=$((64 * 1024))

step() { printf '\n==> %s\n' "$*"; }
die() {
    echo "c-sil: FAIL: $*" >&2
    exit 1
}

# What is missing: QEMU, the target and llvm-tools (scripts/setup-qemu.sh), the Arm C toolchain.
if ! command -v qemu-system-arm >/dev/null 2>&1 || ! rustup target list --installed | grep -qx thumbv7em-none-eabihf; then
    bash scripts/setup-qemu.sh
fi
if ! command -v arm-none-eabi-gcc >/dev/null 2>&1; then
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends gcc-arm-none-eabi binutils-arm-none-eabi >/dev/null
fi
command -v gcc >/dev/null 2>&1 || die "gcc is needed for the host program"

step "Rust: liblowthrust.a for the host and thumbv7em-none-eabihf (profile c-release), guidance_calls, SIL tools"
nice cargo build -q --profile c-release -p lowthrust-onboard-c
nice cargo build -q --profile c-release -p lowthrust-onboard-c --target thumbv7em-none-eabihf
nice cargo build -q --release -p lowthrust-onboard-c --example guidance_calls
nice cargo build -q --release -p lowthrust-firmware-sim --bin random_blob --bin sil_trace
HOST_LIB="$BIN/c-release/liblowthrust.a"
M4_LIB="$BIN/thumbv7em-none-eabihf/c-release/liblowthrust.a"

step "C: the header alone compiles as C99 and C++ with warnings as errors; the host program"
gcc -std=c99 -Wall -Wextra -Werror -pedantic -fsyntax-only -x c onboard/c/include/lowthrust.h
if command -v g++ >/dev/null 2>&1; then
    g++ -std=c++11 -Wall -Wextra -Werror -pedantic -fsyntax-only -x c++ onboard/c/include/lowthrust.h
fi
# -lpthread -ldl -lm: what the host static library's std needs (rustc --print native-static-libs).
gcc -std=c99 -O2 -Wall -Wextra -Werror -pedantic -I onboard/c/include "$EXAMPLES/fly.c" "$EXAMPLES/replay.c" \
    "$HOST_LIB" -lpthread -ldl -lm -o "$OUT/fly"
echo "$OUT/fly"

# The Cortex-M4F image of one case: the blob and the calls linked into flash, replay.c built for
# the case's problem alone (REPLAY_PROBLEM), so the image links that problem's steps and aids and
# no other's, as flight software would.
M4_FLAGS=(-mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16)
m4_image() {
    local blob=$1 calls=$2 elf=$3 problem=$4
    arm-none-eabi-gcc "${M4_FLAGS[@]}" -std=c99 -O2 -ffreestanding -ffunction-sections -fdata-sections \
        -Wall -Wextra -Werror -I onboard/c/include -DREPLAY_PROBLEM="LT_PROBLEM_${problem^^}" \
        -DLT_BLOB_PATH="\"$(realpath "$blob")\"" -DLT_CALLS_PATH="\"$(realpath "$calls")\"" \
        -nostdlib -nostartfiles -T "$M4/mps2-an386.ld" -Wl,--gc-sections -Wl,-z,noexecstack \
        -Wl,-Map="${elf%.elf}.map" \
        "$M4/startup.c" "$M4/semihost.c" "$M4/main.c" "$M4/data.S" "$EXAMPLES/replay.c" "$M4_LIB" -lgcc -o "$elf"
}

step "blobs: seeded random of the four problems (random_blob --seed 1), and refused variants of the int8 transfer blob"
"$BIN/release/random_blob" --seed 1 --out "$OUT/blobs" >/dev/null
"$BIN/release/random_blob" --seed 1 --out "$OUT/blobs" --rendezvous >/dev/null
"$BIN/release/random_blob" --seed 1 --out "$OUT/blobs" --spatial >/dev/null
"$BIN/release/random_blob" --seed 1 --out "$OUT/blobs" --rendezvous --spatial >/dev/null
# put_le FILE OFFSET BYTES VALUE: writes VALUE into FILE at OFFSET, little-endian in BYTES bytes.
put_le() {
    local escapes="" i
    for ((i = 0; i < $3; i++)); do escapes+=$(printf '\\%03o' $((($4 >> (8 * i)) & 0xff))); done
    # shellcheck disable=SC2059 # the format is the bytes as octal escapes
    printf "$escapes" | dd of="$1" bs=1 seek="$2" conv=notrunc status=none
}
good="$OUT/blobs/transfer-int8.blob"
size=$(stat -c %s "$good")
cp "$good" "$OUT/blobs/altered.blob"
offset=$((size / 2))
byte=$(od -An -tu1 -j "$offset" -N1 "$good" | tr -d ' ')
put_le "$OUT/blobs/altered.blob" "$offset" 1 $((byte ^ 0xff))
head -c $((size - 1000)) "$good" >"$OUT/blobs/truncated.blob"
cp "$good" "$OUT/blobs/version.blob"
version=$(od -An -tu2 -j 4 -N2 --endian=little "$good" | tr -d ' ')
put_le "$OUT/blobs/version.blob" 4 2 $((version + 1))
ls -l "$OUT/blobs" | awk 'NR > 1 {print "  " $9 " (" $5 " bytes)"}'

summary=()
failed=0
fail() {
    echo "$*" >&2
    failed=1
}

# commands N: the N f64 bit patterns after each `cmd` word (3 in the plane, 4 in three
# dimensions), which end the line (the C output) or come before `applied` (sil_trace's); any
# other count prints the line as malformed, so the comparison fails.
commands() {
    awk -v n="$1" '{
        for (i = 1; i <= NF; i++) if ($i == "cmd") {
            if (i + n > NF || (i + n < NF && $(i + n + 1) != "applied")) { print "malformed: " $0; next }
            s = $(i + 1)
            for (k = 2; k <= n; k++) s = s " " $(i + k)
            print s
        }
    }'
}

# run_case NAME BLOB transfer|rendezvous|transfer3|rendezvous3 ok|refused
run_case() {
    local name=$1 blob=$2 problem=$3 expect=$4
    local dir="$OUT/$name"
    step "$name: $(basename "$blob"), $problem, expected: $expect"
    mkdir -p "$dir"
    # The flags of guidance_calls and sil_trace for the problem, and its command's length.
    local flag=() command_len=3
    case "$problem" in
        transfer) ;;
        rendezvous) flag=(--rendezvous) ;;
        transfer3) flag=(--spatial) command_len=4 ;;
        rendezvous3) flag=(--rendezvous --spatial) command_len=4 ;;
        *) die "unknown problem $problem" ;;
    esac
    "$BIN/release/examples/guidance_calls" "$blob" "$dir" "${flag[@]}"
    grep -v '^#' "$dir/expected.txt" >"$dir/expected.cmp"
    echo "$(grep -c '^call' "$dir/expected.cmp") guidance calls; $(sed -n 2p "$dir/expected.cmp")"

    # 1. The host C program.
    if ! "$OUT/fly" "$blob" "$dir/calls.bin" >"$dir/host.txt"; then
        fail "$name: the host program failed"
    elif diff "$dir/expected.cmp" "$dir/host.txt" >"$dir/host.diff"; then
        echo "host C program (gcc): output identical to the Rust crates'"
    else
        head -n 10 "$dir/host.diff" >&2
        fail "$name: host C output differs: $dir/host.diff"
    fi

    # 2. Its flight commands against the Rust SIL's own trace (safe mode for a refused blob).
    "$BIN/release/sil_trace" "$blob" "${flag[@]}" >"$dir/sil_trace.txt"
    local steps
    steps=$(grep -c '^step' "$dir/sil_trace.txt")
    grep '^step' "$dir/sil_trace.txt" | commands "$command_len" >"$dir/sil.cmd"
    # awk, not head: head leaves at the Nth line and grep, still writing, dies of SIGPIPE,
    # which pipefail turns into the script's failure.
    grep '^call' "$dir/host.txt" | awk -v n="$steps" 'NR <= n' | commands "$command_len" >"$dir/c.cmd"
    if [ "$steps" -gt 0 ] && cmp -s "$dir/sil.cmd" "$dir/c.cmd"; then
        echo "its $steps flight commands equal sil_trace's, bit for bit"
    else
        fail "$name: the C commands differ from sil_trace's ($dir/sil.cmd, $dir/c.cmd)"
    fi

    # 3. The Cortex-M4F image under QEMU.
    m4_image "$blob" "$dir/calls.bin" "$dir/m4.elf" "$problem"
    local rc=0
    timeout 300 qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none \
        -semihosting-config enable=on,target=native -kernel "$dir/m4.elf" >"$dir/qemu.txt" 2>"$dir/qemu.err" || rc=$?
    if [ $rc -ne 0 ]; then
        cat "$dir/qemu.err" "$dir/qemu.txt" | tail -n 5 >&2
        fail "$name: the image exited with status $rc"
    elif diff "$dir/expected.cmp" <(grep -v '^#' "$dir/qemu.txt") >"$dir/qemu.diff"; then
        echo "Cortex-M4F image (QEMU mps2-an386): output identical to the Rust crates'"
    else
        head -n 10 "$dir/qemu.diff" >&2
        fail "$name: QEMU output differs: $dir/qemu.diff"
    fi
    if arm-none-eabi-nm "$dir/m4.elf" | grep -E 'rust_begin_unwind|panicking' >"$dir/panic.txt"; then
        fail "$name: the image links a panic path: $(head -n 3 "$dir/panic.txt" | tr '\n' ' ')"
    fi

    local load
    load=$(sed -n 2p "$dir/host.txt")
    if [ "$expect" = refused ]; then
        [[ "$load" =~ ^load\ [a-z0-9]+\ -[0-9]+\  ]] || fail "$name: the blob was not refused ($load)"
        # Every call refused with thrust off: throttle bits zero.
        grep '^call' "$dir/host.txt" | grep -v ' refused -4 not_loaded cmd 0000000000000000 ' >/dev/null &&
            fail "$name: a call of a refused policy was not refused with thrust off"
        summary+=("$(printf '%-25s refused: %s' "$name" "${load#load }")")
        return 0
    fi
    [[ "$load" =~ ^load\ [a-z0-9]+\ 0\ ok$ ]] || fail "$name: a good blob was refused ($load)"
    local quant flash ram peak fit=""
    quant=$(sed -n 3p "$dir/host.txt" | awk '{print $3}')
    # Flash: what is loaded (vectors, code, constants with the blob and the calls, .data's
    # image); RAM: .data + .bss, plus the stack's measured peak.
    read -r flash ram < <(arm-none-eabi-size -A "$dir/m4.elf" |
        awk '$1 ~ /^\.(vectors|text|rodata|ARM\.exidx|ARM\.extab)$/ {f += $2} $1 == ".data" {f += $2; r += $2}
             $1 == ".bss" {r += $2} END {print f, r}')
    peak=$(sed -n 's/^# stack high-water \([0-9]*\) bytes.*/\1/p' "$dir/qemu.txt")
    [ -n "$peak" ] || peak=0
    if [ "$quant" = int8 ]; then
        if [ "$flash" -le $FLASH_MAX ] && [ $((ram + peak)) -le $RAM_MAX ]; then
            fit="fits 256 KiB/64 KiB"
        else
            fit="MISSES 256 KiB/64 KiB"
            fail "$name: the int8 image misses the 256 KiB flash / 64 KiB RAM budget"
        fi
    fi
    local blob_bytes calls_bytes
    blob_bytes=$(stat -c %s "$blob")
    calls_bytes=$(stat -c %s "$dir/calls.bin")
    summary+=("$(printf '%-25s %-4s image flash %d B (%.1f KiB; blob %d B, calls %d B, code and rest %d B); RAM %d B static + %d B stack peak %s' \
        "$name" "$quant" "$flash" "$(awk "BEGIN {print $flash / 1024}")" "$blob_bytes" "$calls_bytes" \
        $((flash - blob_bytes - calls_bytes)) "$ram" "$peak" "$fit")")
}

run_case transfer-f32 "$OUT/blobs/transfer-f32.blob" transfer ok
run_case transfer-int8 "$OUT/blobs/transfer-int8.blob" transfer ok
run_case rendezvous-f32 "$OUT/blobs/rendezvous-f32.blob" rendezvous ok
run_case rendezvous-int8 "$OUT/blobs/rendezvous-int8.blob" rendezvous ok
run_case altered "$OUT/blobs/altered.blob" transfer refused
run_case truncated "$OUT/blobs/truncated.blob" transfer refused
run_case version "$OUT/blobs/version.blob" transfer refused
run_case wrong-kind "$OUT/blobs/rendezvous-int8.blob" transfer refused
run_case transfer3-f32 "$OUT/blobs/transfer3-f32.blob" transfer3 ok
run_case transfer3-int8 "$OUT/blobs/transfer3-int8.blob" transfer3 ok
run_case rendezvous3-f32 "$OUT/blobs/rendezvous3-f32.blob" rendezvous3 ok
run_case rendezvous3-int8 "$OUT/blobs/rendezvous3-int8.blob" rendezvous3 ok
run_case transfer3-wrong-dimension "$OUT/blobs/transfer-int8.blob" transfer3 refused
run_case wrong-dimension "$OUT/blobs/transfer3-int8.blob" transfer refused

step "calls files the host program must refuse: another format, another problem, an unknown aid"
# The header's u32s: the format at byte 4 (2: the format before the aids), the problem at byte
# 8; the first call's aid, an f64 at byte 144 (after the header's 16 bytes and the aids' 16 f64s): 3.0.
for refusal in "format 4 4 2" "problem 8 4 4" "aid 144 8 $((0x4008000000000000))"; do
    read -r what offset bytes value <<<"$refusal"
    cp "$OUT/transfer3-int8/calls.bin" "$OUT/unknown-$what.bin"
    put_le "$OUT/unknown-$what.bin" "$offset" "$bytes" "$value"
    if "$OUT/fly" "$OUT/blobs/transfer3-int8.blob" "$OUT/unknown-$what.bin" >/dev/null 2>"$OUT/unknown-$what.err"; then
        fail "the host program flew a calls file of $what $value"
    elif grep -q "$what" "$OUT/unknown-$what.err"; then
        echo "$what $value: $(cat "$OUT/unknown-$what.err")"
    else
        fail "the host program refused a calls file of $what $value without saying so: $(cat "$OUT/unknown-$what.err")"
    fi
done

step "summary ($(($(date +%s) - start)) s)"
printf '%s\n' "${summary[@]}"
[ $failed -eq 0 ] || die "see above"
echo "c-sil: the C-hosted controller commands the Rust SIL's bits on the host and on the Cortex-M4F"
