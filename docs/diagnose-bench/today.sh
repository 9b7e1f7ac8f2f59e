#!/bin/sh
# The diagnose benchmark's tables today (the README's figures): every round's kept results merged, in the order they
# were measured; each dataset's latest diagnosis and latest leave-one-family-out run (`--rescore` repeated).
# Usage: sh docs/diagnose-bench/today.sh [FISHFMU] > today.txt   (writes the merged JSON to ./diagnose_today.json)
FISHFMU=${1:-fishfmu}
R=$(dirname "$0")/results
set --
for f in heldout-r1-a3793f3-2026-11-29 heldout-r2-e56f503-2026-11-29 heldout-r2-c623bcd-2026-11-30 \
         dev20-r1-dc06d09-2026-11-30 compounds-dev-430a9a7-2026-11-30 dev-singles-r2-73689d5-2026-11-30 \
         heldout-r1-singles-open-1f62bbc-2026-11-30 heldout-r1-rigor-open-59bc802-2026-11-30 \
         round3-heldout-1231bf1-2026-11-30 round4-heldout-9efb0cd-2026-11-30 heldout-none-596cf8f-2026-11-30 \
         open-set-scan-596cf8f-2026-11-30 open-set-dev-r1-874b881-2026-11-30 round5-heldout-cab3946-2026-11-30 \
         open-set-dev-r1-cab3946-2026-11-30; do
    set -- "$@" --rescore "$R/$f.json"
done
exec "$FISHFMU" bench diagnose "$@" --json diagnose_today.json
