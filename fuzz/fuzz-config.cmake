# Initial cache of the fuzz build (tools/fuzz: cmake -C fuzz/fuzz-config.cmake ...), which
# also builds the unit tests that tools/sanitize-test runs under ASan + UBSan.
#
# Compiler: Debian bookworm's clang++-16 (packages clang-16, libclang-rt-16-dev), not
# clang-14. The package validator's headers use std::expected, and libstdc++ 12's
# <expected> is only declared when __cpp_concepts >= 202002L. clang 16 implements what
# libstdc++ needs for it (P0848, conditionally trivial special member functions) but still
# advertises __cpp_concepts = 201907L, so we redefine the macro; clang 14 does not
# implement P0848 and fails on <expected> even with the redefinition. The redefinition
# is for this build only: it is never used with GCC, the supported compiler.
set(CMAKE_CXX_COMPILER clang++-16 CACHE STRING "fuzz build compiler")
set(CMAKE_CXX_FLAGS "-Wno-builtin-macro-redefined -U__cpp_concepts -D__cpp_concepts=202002L"
  CACHE STRING "see fuzz/fuzz-config.cmake")
# OSS-Fuzz's optimization and debug level: -O1 keeps the sanitizers' reports exact and
# compiles faster than -O2; line tables are all a stack trace needs.
set(CMAKE_BUILD_TYPE RelWithDebInfo CACHE STRING "")
set(CMAKE_CXX_FLAGS_RELWITHDEBINFO "-O1 -gline-tables-only -DNDEBUG" CACHE STRING "")
set(POLMAP_FUZZ ON CACHE BOOL "")
set(POLMAP_WERROR OFF CACHE BOOL "")
