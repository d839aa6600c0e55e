# Sourced by the bench scripts: shared_data prints the shared data folder, shared/data in the
# nearest parent of the checkout ($ROOT) that has one (a worktree /work/wt/x finds
# /work/shared/data as /work/main does), else $ROOT/../shared/data.
shared_data() {
  local d=$ROOT
  while [ "$d" != / ]; do
    d=$(dirname "$d")
    [ -d "$d/shared/data" ] && { echo "$d/shared/data"; return; }
  done
  echo "$ROOT/../shared/data"
}
