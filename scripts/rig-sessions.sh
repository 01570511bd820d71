#!/usr/bin/env bash
# The rig's held-out sessions (docs/rig.md, "Accuracy"): runs `mouthpiece evaluate` on every
# set, two at a time, one output file per job, then summarises them against the targets.
#
# Usage: scripts/rig-sessions.sh OUTDIR [SET...]
#   SET: default (the 12 sessions `evaluate` runs by default, seeds 1-3), log (the 164 others
#   of docs/lab/rig-accuracy-log.md, seeds 4-9 and 11-110: 6, 10 and 20 s), s121 (seeds 121-140 at
#   evaluate's defaults), s141 (seeds 141-160 at the defaults). Without a SET: all of them
#   (336 sessions, about 13 minutes on two cores with a debug build).
# MOUTHPIECE: the binary (default target/debug/mouthpiece; build it first).
set -euo pipefail
out=${1:?usage: scripts/rig-sessions.sh OUTDIR [SET...]}
shift
sets=("$@")
[ ${#sets[@]} -eq 0 ] && sets=(default log s121 s141)
cd "$(dirname "$0")/.."
bin=${MOUTHPIECE:-target/debug/mouthpiece}
[ -x "$bin" ] || { echo "no binary at $bin (cargo build -p mouthpiece)" >&2; exit 2; }
mkdir -p "$out"
jobs=()
both="--noise kinect,realsense"
for set in "${sets[@]}"; do
    case $set in
    default) jobs+=("default|--seeds 1,2,3 $both --head-motion mild,strong --seconds 6") ;;
    log)
        for s in 4 5 6 7 8 9; do jobs+=("a_$s|--seeds $s $both --head-motion mild,strong --seconds 6"); done
        for s in 31 32 33 34 35 11 12 13 21 22; do jobs+=("bk_$s|--seeds $s --noise kinect --head-motion strong --seconds 10"); done
        for s in 31 32 33; do jobs+=("br_$s|--seeds $s --noise realsense --head-motion mild,strong --seconds 10"); done
        for s in 1 2 3 4 5 6 7 8 9 11 12 13 21; do jobs+=("c_$s|--seeds $s $both --head-motion strong --seconds 20"); done
        for s in 14 15 16 17 18 19 20 23 24 25; do jobs+=("ck_$s|--seeds $s --noise kinect --head-motion strong --seconds 20"); done
        for s in $(seq 41 52) $(seq 61 72) $(seq 101 110); do jobs+=("d_$s|--seeds $s $both --head-motion strong --seconds 10"); done
        for s in $(seq 81 90); do jobs+=("e_$s|--seeds $s $both --head-motion strong --seconds 20"); done
        ;;
    s121) for s in $(seq 121 140); do jobs+=("f_$s|--seeds $s"); done ;;
    s141) for s in $(seq 141 160); do jobs+=("g_$s|--seeds $s"); done ;;
    *) echo "unknown set $set (default, log, s121, s141)" >&2; exit 2 ;;
    esac
done
printf '%s\n' "${jobs[@]}" | xargs -P 2 -I{} bash -c '
    job="{}"; name=${job%%|*}; args=${job#*|}
    '"$bin"' evaluate $args --character config/characters/human.toml --per-curve \
        > '"$out"'/$name.txt 2> /dev/null'
python3 scripts/rig-misses.py "$out"
