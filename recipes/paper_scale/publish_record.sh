#!/usr/bin/env bash
# Copies one finished paper-scale run into the committed records (docs/results/), ready for `git add`:
#
#   recipes/paper_scale/publish_record.sh EVAL_DIR RECORD_DIR [TRAIN_DIR]
#
# EVAL_DIR: a finished `navformer evaluate` folder; RECORD_DIR gets its run.json, summary.md and
# episodes.jsonl as episodes.jsonl.gz (the tools read either). TRAIN_DIR (optional): the `navformer train`
# output folder of the evaluated checkpoint; RECORD_DIR/training/ gets its train_config.json and its losses'
# CSV scalars (logs/<exp_name>/scalars/loss*.csv and validation/*.csv: the training and held-out losses), so the record keeps how the weights
# were trained when the run folder, outside git, is gone. Each file is written to a temporary name and
# renamed, so an interrupted copy never leaves a truncated record. Run from the repository root; the queue
# of reproduce.md section 3 runs it after each Table I evaluation.
set -euo pipefail
if [ $# -lt 2 ] || [ $# -gt 3 ]; then
    sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 2
fi
eval_dir=$1 record=$2 train_dir=${3:-}
for f in run.json summary.md episodes.jsonl; do
    [ -f "$eval_dir/$f" ] || { echo "publish_record.sh: $eval_dir/$f does not exist: expected a finished evaluation folder" >&2; exit 2; }
done
if [ -n "$train_dir" ] && [ ! -f "$train_dir/train_config.json" ]; then
    echo "publish_record.sh: $train_dir/train_config.json does not exist: expected a navformer train output folder" >&2; exit 2
fi
put() {  # put SOURCE DEST: copy atomically
    mkdir -p "$(dirname "$2")"
    cp "$1" "$2.tmp" && mv "$2.tmp" "$2"
}
put "$eval_dir/run.json" "$record/run.json"
put "$eval_dir/summary.md" "$record/summary.md"
gzip -n -c "$eval_dir/episodes.jsonl" > "$record/episodes.jsonl.gz.tmp" && mv "$record/episodes.jsonl.gz.tmp" "$record/episodes.jsonl.gz"
if [ -n "$train_dir" ]; then
    put "$train_dir/train_config.json" "$record/training/train_config.json"
    (cd "$train_dir/logs" && find . -type f \( -path '*/scalars/loss*.csv' -o -path '*/scalars/validation/*.csv' \)) | while read -r csv; do
        # logs/<exp_name>/scalars/X.csv -> training/scalars/X.csv
        put "$train_dir/logs/$csv" "$record/training/scalars/${csv#*/scalars/}"
    done
fi
echo "publish_record.sh: $record"
