# Sourced by the benchmark scripts that take one option, --write-docs: sets write_docs to 1
# when it is given, and refuses any other argument (exit 2, naming the script).
write_docs=0
for arg in "$@"; do
  case "$arg" in
    --write-docs) write_docs=1 ;;
    *) echo "$(basename "$0"): unknown option '$arg' (allowed: --write-docs)" >&2; exit 2 ;;
  esac
done
