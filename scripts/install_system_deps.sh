#!/usr/bin/env bash
# Installs the Debian/Ubuntu system library that Open3D needs (libusb-1.0).
# Idempotent: does nothing when the library is already present.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so'; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "error: libusb-1.0 is missing and I am not root (install it with: apt-get install libusb-1.0-0)" >&2; exit 1
  fi
fi
if command -v apt-get >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null; }
else
  echo "error: libusb-1.0 is missing and apt-get is not available; install libusb-1.0 with your package manager" >&2
  exit 1
fi
