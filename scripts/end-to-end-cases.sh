# Sourced by scripts/test.sh and scripts/test-aarch64.sh: a ctest -E pattern of the four
# longest cases, which run the learned tracker end to end through the command line (a tracked
# flight, eval across 11 years with the tilt prior and with an altimeter, eval on
# Christchurch). 3-11 s each natively, 144-206 s each
# under GCC's ASan + UBSan at -O2 and 10-30 minutes each under qemu, where on session 63's AVX2 host they
# took CI past its 90 minutes; the sanitizer and qemu suites leave them to the native ones.
END_TO_END_CASES="the learned tracker confirms a prediction that is already right|eval's default tilt prior: across 11 years"
END_TO_END_CASES+="|eval on Christchurch: the manifest's registration sigma|eval --altimeter: the priors' altitude"
