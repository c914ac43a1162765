#!/usr/bin/env bash
# allantools peer for `rigslam-calibrate noise`: installs allantools
# from PyPI in ./.venv-peers (gitignored) and recreates
# fixtures/allan/adis16405_oadev.json, the overlapping Allan deviation of the
# real ADIS16405 static log per axis. fixtures/allan/README.md records
# version, date and command.
#
# Usage: bench/peers/allan_adis16405.sh   (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA=$(realpath "${RIGSLAM_SHARED_DATA:-../shared/data}")/imu
if [ ! -x .venv-peers/bin/python ] || ! .venv-peers/bin/python -c 'import imucal, allantools' 2>/dev/null; then
  python3 -m venv .venv-peers
  .venv-peers/bin/pip install imucal allantools
fi
.venv-peers/bin/python bench/peers/allan_adis16405.py \
  "$DATA/adis16405_static_100hz_2p78h.csv.gz" fixtures/allan/adis16405_oadev.json
