#!/usr/bin/env bash
# Make a libLLVM >= 16 available for Mitsuba's LLVM variants (llvm_ad_rgb), or say why not.
# Debian's libllvm19 works; the system's LLVM 14/15 crash inside Dr.Jit (DESIGN.md). Without it,
# SCET renders with scalar_rgb, 4-9x slower.
set -u
for lib in /usr/lib/x86_64-linux-gnu/libLLVM-19.so* /usr/lib/aarch64-linux-gnu/libLLVM-19.so* \
           /usr/lib/llvm-19/lib/libLLVM*.so*; do
    [ -e "$lib" ] && { echo "libLLVM 19 found: $lib"; exit 0; }
done
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "notice: libLLVM 19 not found and cannot install it (not root, or no apt-get);" \
         "Mitsuba will fall back to the scalar_rgb variant (slower)." >&2
    exit 0
fi
echo "installing Debian's libllvm19 for Mitsuba's LLVM backend ..."
if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19; } >/tmp/scet-apt.log 2>&1; then
    echo "notice: apt-get could not install libllvm19 (see /tmp/scet-apt.log);" \
         "Mitsuba will fall back to the scalar_rgb variant (slower)." >&2
fi
exit 0
