# Compile settings shared by every terralign target.

# Threading is ours: Eigen must never spawn its own threads.
add_compile_definitions(EIGEN_DONT_PARALLELIZE)
# An uninitialised Eigen matrix shows up as NaN in debug builds.
add_compile_definitions($<$<CONFIG:Debug>:EIGEN_INITIALIZE_MATRICES_BY_NAN>)

# One floating-point policy on every machine: nothing fuses a * b + c into one rounding but
# what the code says (the kernels' multiply-add intrinsics, std::fma). GCC contracts by default
# where the target has FMA (aarch64 always, x86-64 in the files built with -mfma), which gave
# aarch64 other bits than x86-64 in every module; the SIMD kernels' scalar twins need it too.
add_compile_options(-ffp-contract=off)
# The same policy refuses the flags that let the compiler reorder or assume away what the code
# says (and that turn std::isfinite, the bad-input checks' test, into true): -ffast-math, -Ofast
# and their parts. terralign/geo/numeric.hpp refuses them again where a flag reaches a
# translation unit some other way.
string(TOUPPER "${CMAKE_BUILD_TYPE}" terralign_build_type)
set(terralign_flags "${CMAKE_CXX_FLAGS} ${CMAKE_CXX_FLAGS_${terralign_build_type}}")
foreach(flag -ffast-math -Ofast -ffinite-math-only -fassociative-math -freciprocal-math
             -funsafe-math-optimizations -fno-signed-zeros)
  string(FIND " ${terralign_flags} " " ${flag} " at)
  if(NOT at EQUAL -1)
    message(FATAL_ERROR "${flag} breaks IEEE floating point, which terralign needs as written: "
                        "take it out of the C++ flags (\"${terralign_flags}\")")
  endif()
endforeach()

if(TERRALIGN_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all)
  add_link_options(-fsanitize=address,undefined)
endif()

# Warnings for terralign's own targets (not for embedding projects).
function(terralign_warnings target)
  if(NOT TERRALIGN_TOP_LEVEL)
    return()
  endif()
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wshadow -Wfloat-conversion
                                           -Wnon-virtual-dtor -Wpedantic)
  if(TERRALIGN_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()

if(TERRALIGN_FUZZ)
  # Coverage instrumentation in the libraries too, so the fuzzers see inside the parsers.
  add_compile_options(-fsanitize=fuzzer-no-link)
endif()
