#!/bin/sh
# Make a libLLVM >= 16 available for Dr.Jit's LLVM (CPU) backend.
# Debian's default libLLVM 15 makes Dr.Jit abort the process, so imcsim never loads it
# (scene/variant.py picks the scalar variant instead). As root we install libllvm19.
have_llvm16() {
    for f in /usr/lib/*/libLLVM*.so* /usr/lib/llvm-*/lib/libLLVM*.so* /usr/lib64/libLLVM*.so* /usr/local/lib/libLLVM*.so*; do
        [ -e "$f" ] || continue
        v=$(basename "$f" | sed -n 's/^libLLVM[.-]\{0,1\}\([0-9][0-9]*\).*/\1/p')
        [ -n "$v" ] && [ "$v" -ge 16 ] && return 0
    done
    return 1
}
have_llvm16 && exit 0
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "imcsim setup: installing Debian libllvm19 for Dr.Jit's LLVM backend"
    (apt-get install -y -qq libllvm19 >/dev/null 2>&1 || \
        (apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq libllvm19 >/dev/null 2>&1)) || true
    have_llvm16 && exit 0
fi
echo "imcsim setup: WARNING no libLLVM >= 16 (install Debian 'libllvm19' as root); rendering falls back to Mitsuba's slow scalar variant"
exit 0
