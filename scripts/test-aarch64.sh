#!/usr/bin/env bash
# The aarch64 build and its tests under qemu-user (CI's second stage): scripts/test-arm-linux.sh.
exec bash "$(dirname "$0")/test-arm-linux.sh" aarch64
