#!/usr/bin/env bash
# Make the AVR toolchain available for the strobe firmware (hardware/firmware): avr-gcc and
# avr-libc to build it, simavr (libsimavr + its header) to run it in the tests. Debian's
# gcc-avr, avr-libc, simavr and libsimavr-dev (HARDWARE.md Sec. 8); about 130 MB installed.
# Without them `make firmware` cannot build and the firmware tests skip, saying why.
set -u
have() { command -v avr-gcc >/dev/null 2>&1 && [ -e /usr/include/simavr/avr/avr_mcu_section.h ] \
         && ls /usr/lib/*/libsimavr.so.2 >/dev/null 2>&1; }
if have; then
    echo "AVR toolchain found: $(command -v avr-gcc), simavr $(dpkg-query -W -f='${Version}' simavr 2>/dev/null || echo '?')"
    exit 0
fi
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "notice: avr-gcc/simavr not found and cannot install them (not root, or no apt-get);" \
         "install gcc-avr avr-libc simavr libsimavr-dev to build the strobe firmware;" \
         "its tests will skip." >&2
    exit 0
fi
echo "installing Debian's gcc-avr avr-libc simavr libsimavr-dev for the strobe firmware ..."
if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        gcc-avr avr-libc simavr libsimavr-dev; } >/tmp/scet-apt-avr.log 2>&1; then
    echo "notice: apt-get could not install the AVR toolchain (see /tmp/scet-apt-avr.log);" \
         "the firmware tests will skip." >&2
fi
exit 0
