#!/usr/bin/env bash
# Installs LLVM 19 (Debian's and Ubuntu's libllvm19) for Mitsuba's fast llvm_ad_rgb variant,
# which benches/peer_mitsuba.py times against (without it, it falls back to scalar_rgb and
# says so). Nothing else in the project needs it: the tests use scalar_rgb.
#
#   scripts/install-llvm.sh            # apt-get install libllvm19 (sudo if not root)
#   scripts/install-llvm.sh --check    # only report whether llvm_ad_rgb renders here
#
# Dr.Jit loads the first libLLVM it finds; where an older one is found first (Debian 12
# ships libLLVM-14 and -15 beside it, which load, then abort the process on a renderer's
# kernels), set DRJIT_LIBLLVM_PATH to the path this script prints.
set -euo pipefail

python="${PYTHON:-python3}"

check() {
    # The same test the bench makes, in a child process (a wrong LLVM aborts it).
    if "$python" -c 'import sys, viscache_rs.mitsuba as m; sys.exit(0 if m.llvm_available() else 1)' \
        2>/dev/null; then
        echo "llvm_ad_rgb renders here"
    else
        echo "llvm_ad_rgb does NOT render here (or viscache_rs/mitsuba is not installed for $python)"
        return 1
    fi
}

if [[ "${1:-}" == "--check" ]]; then
    check
    exit
fi

if ! command -v apt-get >/dev/null; then
    echo "no apt-get: install LLVM 19 with your system's package manager, then set" >&2
    echo "DRJIT_LIBLLVM_PATH to its libLLVM shared library" >&2
    exit 1
fi
sudo=()
if [[ "$(id -u)" != 0 ]]; then
    sudo=(sudo)
fi
if ! apt-cache show libllvm19 >/dev/null 2>&1; then
    "${sudo[@]}" apt-get update
fi
"${sudo[@]}" apt-get install -y --no-install-recommends libllvm19

lib="$(dpkg -L libllvm19 | grep -E '/libLLVM[^/]*\.so[^/]*$' | head -n 1)"
if [[ -z "$lib" ]]; then
    echo "libllvm19 is installed but holds no libLLVM*.so: set DRJIT_LIBLLVM_PATH by hand" >&2
    exit 1
fi
echo "LLVM 19: $lib"
echo "If an older libLLVM is found first, add to your shell's profile:"
echo "    export DRJIT_LIBLLVM_PATH=$lib"
DRJIT_LIBLLVM_PATH="$lib" check || true
