# Precompiled headers (CI time): header parsing is most of a translation unit's compile
# time here (measured 2026-12-06: -fsyntax-only is 60 % of an -O2 compile of the store and
# server sources; nlohmann/json, Eigen and GoogleTest cost 2-3.5 s each per TU), and CI
# compiles ~290 TUs twice with GCC. Two precompiled headers are built once and reused by
# every target (REUSE_FROM): polmap_pch (the standard library, Eigen, nlohmann/json) for
# libraries and programs, polmap_test_pch (the same plus GoogleTest) for the tests. The
# clang fuzz and sanitizer build (fuzz/fuzz-config.cmake) uses them too: its
# __cpp_concepts redefinition is in CMAKE_CXX_FLAGS, so the headers are precompiled with it
# (that tree's fuzz targets and sanitized tests: 951 s without, 603 s with them and -O1,
# measured 2026-12-07 on 2 cores).
option(POLMAP_PCH "Precompile the common headers once for every target" ON)
set(POLMAP_PCH_HEADERS <algorithm> <array> <atomic> <chrono> <cmath> <cstdint> <cstdio>
  <cstring> <filesystem> <fstream> <functional> <limits> <map> <memory> <numbers> <optional>
  <random> <set> <span> <sstream> <string> <string_view> <thread> <unordered_map> <utility>
  <vector> <Eigen/Core> <Eigen/Dense> <nlohmann/json.hpp>)

# The targets that own the precompiled headers: static libraries with an empty source,
# compiled with exactly the options polmap_target_defaults gives (GCC rejects a PCH built
# with other code-generation flags).
function(polmap_define_pch)
  if(NOT POLMAP_PCH)
    return()
  endif()
  file(WRITE ${CMAKE_BINARY_DIR}/polmap_pch_anchor.cpp "// owner of the precompiled header\n")
  foreach(_pch polmap_pch polmap_test_pch)
    add_library(${_pch} STATIC ${CMAKE_BINARY_DIR}/polmap_pch_anchor.cpp)
    target_link_libraries(${_pch} PRIVATE Eigen3::Eigen nlohmann_json::nlohmann_json)
    _polmap_standard_and_warnings(${_pch})
    target_precompile_headers(${_pch} PRIVATE ${POLMAP_PCH_HEADERS})
  endforeach()
  target_link_libraries(polmap_test_pch PRIVATE GTest::gtest)
  target_precompile_headers(polmap_test_pch PRIVATE <gtest/gtest.h>)
endfunction()

function(_polmap_standard_and_warnings target)
  target_compile_features(${target} PUBLIC cxx_std_23)
  set_target_properties(${target} PROPERTIES CXX_EXTENSIONS OFF)
  get_target_property(_type ${target} TYPE)
  if(NOT _type STREQUAL "INTERFACE_LIBRARY")
    target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic
      $<$<BOOL:${POLMAP_WERROR}>:-Werror -Wno-error=deprecated-declarations>)
  endif()
endfunction()

# One place that sets language standard and warnings for every polmap target, and the
# shared precompiled header (PCH_FROM: polmap_pch by default, polmap_test_pch for tests).
function(polmap_target_defaults target)
  cmake_parse_arguments(ARG "" "PCH_FROM" "" ${ARGN})
  _polmap_standard_and_warnings(${target})
  get_target_property(_type ${target} TYPE)
  if(POLMAP_PCH AND NOT _type STREQUAL "INTERFACE_LIBRARY")
    if(NOT ARG_PCH_FROM)
      set(ARG_PCH_FROM polmap_pch)
    endif()
    target_precompile_headers(${target} REUSE_FROM ${ARG_PCH_FROM})
  endif()
endfunction()

# polmap_export_target(TARGET): puts a library target into the installed CMake
# package (export set polmapTargets, see the top-level CMakeLists.txt). polmap_<x>
# gets the alias polmap::<x> for in-tree use and is imported by find_package(polmap)
# consumers under the same name. Only module libraries (and the helper targets they
# link) are exported; tools/ (polmap_sim, polmap_eval), tests and benches are not.
function(polmap_export_target name)
  string(REGEX REPLACE "^polmap_" "" _export_name ${name})
  add_library(polmap::${_export_name} ALIAS ${name})
  set_target_properties(${name} PROPERTIES EXPORT_NAME ${_export_name})
  install(TARGETS ${name} EXPORT polmapTargets
    ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
    LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
    RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  # tools/check-install builds exactly these (target polmap_installable).
  set_property(GLOBAL APPEND PROPERTY POLMAP_EXPORTED_TARGETS ${name})
endfunction()

# polmap_add_library(NAME SOURCES ... DEPS ...): a module library with
# include/ as its public include root (installed into <prefix>/include).
function(polmap_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  if(NOT ARG_SOURCES)
    # A module may be header-only for a while; keep it a real library target.
    file(WRITE ${CMAKE_CURRENT_BINARY_DIR}/${name}_anchor.cpp "// header-only module\n")
    set(ARG_SOURCES ${CMAKE_CURRENT_BINARY_DIR}/${name}_anchor.cpp)
  endif()
  add_library(${name} ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC
    $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/include>
    $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>)
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
  polmap_target_defaults(${name})
  polmap_export_target(${name})
  if(EXISTS ${CMAKE_CURRENT_SOURCE_DIR}/include)
    # Modules share include/polmap/<module>/ trees (e.g. localization_client and
    # its fetch/ target); the installed directories merge.
    install(DIRECTORY ${CMAKE_CURRENT_SOURCE_DIR}/include/
      DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
  endif()
endfunction()

# polmap_add_test(NAME SOURCES ... DEPS ... [LABELS ...]): one GoogleTest binary
# registered with ctest (tests run from the build dir; POLMAP_SOURCE_DIR and
# POLMAP_DATA_DIR locate checked-in sources and data).
function(polmap_add_test name)
  cmake_parse_arguments(ARG "" "TIMEOUT" "SOURCES;DEPS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} polmap_util GTest::gtest_main)
  # Shared fixtures are included as "<module>/<fixture>.hpp" from the tests/ root.
  target_include_directories(${name} PRIVATE ${CMAKE_SOURCE_DIR}/tests)
  target_compile_definitions(${name} PRIVATE
    POLMAP_SOURCE_DIR="${CMAKE_SOURCE_DIR}"
    POLMAP_DATA_DIR="${CMAKE_SOURCE_DIR}/data"
    POLMAP_BINARY_DIR="${CMAKE_BINARY_DIR}")
  polmap_target_defaults(${name} PCH_FROM polmap_test_pch)
  include(GoogleTest)
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 300)
  endif()
  # CMake 3.25's test discovery cannot pass a list in PROPERTIES, so the labels are joined
  # into one ("fast:radar"); ctest -L takes a regular expression, so `-L fast` and
  # `-L radar` both select it.
  string(REPLACE ";" ":" _labels "${ARG_LABELS}")
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60
    PROPERTIES TIMEOUT ${ARG_TIMEOUT} LABELS "${_labels}")
endfunction()
