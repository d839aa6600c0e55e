# Sourced by the bench scripts: timing a cold `flyover run` and reading its --log-json lines.
now() { date +%s%N; }
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.3f", (b - a) / 1e9 }'; }
# The first_pair event's seconds since the start, and the process CPU seconds at it, of a log.
first_pair_seconds() { sed -n 's/.*"event":"first_pair".*"seconds_since_start":\([0-9.eE+-]*\).*/\1/p' "$1" | head -1; }
first_pair_cpu() { sed -n 's/.*"cpu_seconds":\([0-9.eE+-]*\),"event":"first_pair".*/\1/p' "$1" | head -1; }
# The process CPU seconds of the log's last line (the run's end).
last_cpu() { sed -n 's/.*"cpu_seconds":\([0-9.eE+-]*\).*/\1/p' "$1" | tail -1; }
# Numbers on stdin, one a line -> "median min max n".
median_min_max() {
  sort -g | awk '{ t[NR] = $1 } END {
    printf "%.3f %.3f %.3f %d\n", (NR % 2 ? t[(NR + 1) / 2] : (t[NR / 2] + t[NR / 2 + 1]) / 2), t[1], t[NR], NR }'
}
