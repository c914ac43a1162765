#!/bin/sh
# Checks systemd/rigslamd.service: `systemd-analyze verify` (with ExecStart
# pointed at this build's rigslamd, since /usr/local/bin may not hold one)
# and the offline security review, whose exposure must be 2.5 or lower.
# RIGSLAMD=path picks the binary (default: target/release/rigslamd).
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
bin="${RIGSLAMD:-$root/target/release/rigslamd}"
[ -x "$bin" ] || { echo "build first: cargo build --release -p rigslam --bins" >&2; exit 1; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sed "s#/usr/local/bin/rigslamd#$bin#g" "$root/systemd/rigslamd.service" >"$tmp/rigslamd.service"
systemd-analyze verify "$tmp/rigslamd.service"
echo "systemd-analyze verify: ok"
# --threshold=25: exit status non-zero above exposure 2.5.
rc=0
systemd-analyze security --offline=true --threshold=25 "$tmp/rigslamd.service" >"$tmp/security" 2>&1 || rc=$?
tail -n 1 "$tmp/security"
if [ "$rc" -ne 0 ]; then
    cat "$tmp/security" >&2
    echo "systemd-analyze security: exposure above 2.5 (exit $rc)" >&2
    exit 1
fi
# The same with the live view's drop-in (systemd/viewer.conf) beside it,
# which the offline review reads as systemd would.
mkdir -p "$tmp/viewer/rigslamd.service.d"
cp "$tmp/rigslamd.service" "$tmp/viewer/rigslamd.service"
cp "$root/systemd/viewer.conf" "$tmp/viewer/rigslamd.service.d/viewer.conf"
systemd-analyze verify "$tmp/viewer/rigslamd.service"
rc=0
systemd-analyze security --offline=true --threshold=25 "$tmp/viewer/rigslamd.service" >"$tmp/security-viewer" 2>&1 || rc=$?
echo "with viewer.conf: $(tail -n 1 "$tmp/security-viewer")"
if [ "$rc" -ne 0 ]; then
    cat "$tmp/security-viewer" >&2
    echo "systemd-analyze security with viewer.conf: exposure above 2.5 (exit $rc)" >&2
    exit 1
fi
