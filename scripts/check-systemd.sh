#!/bin/sh
# Checks systemd/rigslamd.service: `systemd-analyze verify` (with ExecStart
# pointed at this build's rigslamd, since /usr/local/bin may not hold one)
# and the offline security review, whose exposure must be 2.5 or lower.
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
bin="$root/target/release/rigslamd"
[ -x "$bin" ] || { echo "build first: cargo build --release -p rigslam --bins" >&2; exit 1; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sed "s#/usr/local/bin/rigslamd#$bin#g" "$root/systemd/rigslamd.service" >"$tmp/rigslamd.service"
systemd-analyze verify "$tmp/rigslamd.service"
echo "systemd-analyze verify: ok"
systemd-analyze security --offline=true --threshold=25 "$tmp/rigslamd.service" | tail -n 1
