#!/usr/bin/env bash
# Runs a queue of long jobs (collection, training, evaluation at the paper's scale) one after the other, each
# on a frozen copy of the code, resumable across machine restarts and sessions.
#
#   recipes/paper_scale/run_queue.sh QUEUE RUN_DIR        (from anywhere; jobs run in the repository root)
#   nohup recipes/paper_scale/run_queue.sh QUEUE RUN_DIR >/dev/null 2>&1 &     (in the background)
#
# QUEUE: lines NAME <tab> CODE <tab> COMMAND ('#' starts a comment). CODE is a git revision of this repository:
# the job runs that commit's navformer_rl, installed once into RUN_DIR/venv/CODE (a later commit on main never
# changes a running study); '-' runs in the environment the runner was started from. The queue is read again
# before each job, so jobs not yet started may be edited, reordered or added while it runs.
# Each job runs until it succeeds once (RUN_DIR/done/NAME then holds its seconds; it is never rerun). A job
# that exits with an error is marked RUN_DIR/failed/NAME (its output in RUN_DIR/logs/NAME.log) and skipped;
# delete the mark to retry it. A job killed by a signal (the machine or session stopping) is left unmarked:
# the next start reruns its command, which resumes it (training with resume=true from its last checkpoint,
# collection by shard, evaluation by finished episode). `touch RUN_DIR/STOP` stops the runner after the
# current job. PIPELINE_THREADS sets each job's OMP_NUM_THREADS (default 2). RUN_DIR/runner.log says what ran.
set -u
if [ $# -ne 2 ]; then
    sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; exit 2
fi
QUEUE="$(realpath "$1")"
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$REPO"
mkdir -p "$2"
RUN_DIR="$(realpath "$2")"
[ -f "$QUEUE" ] || { echo "run_queue.sh: no queue file $QUEUE" >&2; exit 2; }
mkdir -p "$RUN_DIR/done" "$RUN_DIR/failed" "$RUN_DIR/logs"
if [ -e "$RUN_DIR/runner.pid" ] && kill -0 "$(cat "$RUN_DIR/runner.pid")" 2>/dev/null; then
    echo "run_queue.sh: a runner already works on $RUN_DIR (pid $(cat "$RUN_DIR/runner.pid"))" >&2; exit 1
fi
echo $$ > "$RUN_DIR/runner.pid"
log() { echo "$(date -u +%FT%TZ) $*" >> "$RUN_DIR/runner.log"; }
child=""
trap 'log "stopped by a signal"; [ -n "$child" ] && kill -TERM -- "-$child" 2>/dev/null; wait; rm -f "$RUN_DIR/runner.pid"; exit 143' TERM INT HUP

install_code() {  # install_code REV: the frozen copy of REV's code in RUN_DIR/venv/REV (once)
    local rev=$1 code="$RUN_DIR/code/$1" venv="$RUN_DIR/venv/$1"
    [ -e "$venv/.installed" ] && return 0
    git rev-parse --verify --quiet "$rev^{commit}" > /dev/null || { log "unknown revision $rev"; return 1; }
    rm -rf "$code" "$venv" && mkdir -p "$code" || return 1
    git archive "$rev" | tar -x -C "$code" || return 1
    git rev-parse "$rev^{commit}" > "$code/COMMIT"
    local torch=(torch==2.13.0)
    [ -d /opt/wheels ] && torch+=(--find-links /opt/wheels)
    [ -n "${NAVFORMER_TORCH_INDEX:-}" ] && torch+=(--extra-index-url "$NAVFORMER_TORCH_INDEX")
    local pins=()  # the tested dependency versions of the working tree's constraints.txt, for every revision
    [ -f "$REPO/constraints.txt" ] && pins=(-c "$REPO/constraints.txt")
    python3 -m venv "$venv" && "$venv/bin/pip" install -q "${torch[@]}" \
        && "$venv/bin/pip" install -q "${pins[@]}" "$code" && touch "$venv/.installed"
}

while true; do
    if [ -e "$RUN_DIR/STOP" ]; then log "STOP found: stopping"; rm -f "$RUN_DIR/runner.pid"; exit 0; fi
    name="" code="" cmd=""
    while IFS=$'\t' read -r n c rest; do
        [ -z "$n" ] || [ "${n:0:1}" = "#" ] && continue
        { [ -e "$RUN_DIR/done/$n" ] || [ -e "$RUN_DIR/failed/$n" ]; } && continue
        name=$n code=$c cmd=$rest
        break
    done < "$QUEUE"
    if [ -z "$name" ]; then log "queue finished"; rm -f "$RUN_DIR/runner.pid"; exit 0; fi
    path="$PATH"
    if [ "$code" != "-" ]; then
        if ! install_code "$code" >> "$RUN_DIR/logs/$name.log" 2>&1; then
            echo "could not install revision $code" > "$RUN_DIR/failed/$name"; log "FAILED $name: revision $code"; continue
        fi
        path="$RUN_DIR/venv/$code/bin:$PATH"
    fi
    log "start $name (code $code)"
    start=$(date +%s)
    # PYTHONSAFEPATH: the frozen package, never the working tree's navformer_rl in the current directory
    setsid env PATH="$path" OMP_NUM_THREADS="${PIPELINE_THREADS:-2}" PYTHONSAFEPATH=1 RL_LOGGING_LEVEL=WARNING \
        GLIBC_TUNABLES="${GLIBC_TUNABLES:-glibc.malloc.hugetlb=1}" bash -c "$cmd" >> "$RUN_DIR/logs/$name.log" 2>&1 &
    child=$!
    wait "$child"; rc=$?
    child=""
    took=$(( $(date +%s) - start ))
    if [ "$rc" -eq 0 ]; then
        echo "$took" > "$RUN_DIR/done/$name"; log "done $name in ${took} s"
    elif [ "$rc" -ge 128 ]; then
        log "$name killed (exit $rc) after ${took} s: the next start resumes it"; rm -f "$RUN_DIR/runner.pid"; exit "$rc"
    else
        echo "exit $rc" > "$RUN_DIR/failed/$name"; log "FAILED $name (exit $rc) after ${took} s: $RUN_DIR/logs/$name.log"
    fi
done
