#!/bin/sh
# Fetch the Olinda case (scenarios/olinda.yaml): a Landsat-7 ETM+ scene of Olinda, Brazil
# (6 bands, 28.5 m, UTM 25 S) and its 90 m DEM, as Debian's r-cran-stars package ships them
# (tif/L7_ETMs.tif, tif/olinda_dem_utm25s.tif; no R needed: the .deb is unpacked).
# Idempotent; without apt-get (or when the download fails) one line says so and it exits 0.
set -u
DEST="${1:-scenarios/data/olinda}"
[ -f "$DEST/L7_ETMs.tif" ] && [ -f "$DEST/olinda_dem_utm25s.tif" ] && exit 0
if ! command -v apt-get >/dev/null 2>&1 || ! command -v dpkg-deb >/dev/null 2>&1; then
    echo "imcsim data: skipped the Olinda case (no apt-get / dpkg-deb: fetch Debian's r-cran-stars by hand into $DEST)"
    exit 0
fi
TMP=$(mktemp -d) || exit 0
trap 'rm -rf "$TMP"' EXIT
( cd "$TMP" && (apt-get download r-cran-stars >/dev/null 2>&1 || \
    ([ "$(id -u)" = "0" ] && apt-get update -qq >/dev/null 2>&1 && \
     apt-get download r-cran-stars >/dev/null 2>&1)) )
DEB=$(ls "$TMP"/r-cran-stars_*.deb 2>/dev/null | head -n 1)
if [ -z "$DEB" ]; then
    echo "imcsim data: skipped the Olinda case (apt-get download r-cran-stars failed: no Debian archive reachable, or run apt-get update as root)"
    exit 0
fi
dpkg-deb -x "$DEB" "$TMP/x" && mkdir -p "$DEST" && \
    cp "$(find "$TMP/x" -name L7_ETMs.tif | head -n 1)" \
       "$(find "$TMP/x" -name olinda_dem_utm25s.tif | head -n 1)" "$DEST"/ && \
    echo "imcsim data: the Olinda case (Landsat-7 ETM+ scene and 90 m DEM from $(basename "$DEB")) in $DEST" || \
    echo "imcsim data: skipped the Olinda case (unpacking $(basename "$DEB") failed)"
exit 0
