# Precompiled headers: OpenVDB's and nlohmann::json's headers take most of a translation unit's
# compile time (openvdb/openvdb.h alone ~10 s), and nearly every one includes them. They are
# compiled once, by flyover_pch (and with GoogleTest by flyover_test_pch), and every target
# reuses that (all targets share the compiler flags that matter: the OpenVDB definitions, -O,
# -std). FLYOVER_PCH=OFF compiles without them.
option(FLYOVER_PCH "Precompile the heavy third-party headers once for all targets" ON)

set(FLYOVER_PCH_HEADERS
  <openvdb/openvdb.h>
  <nlohmann/json.hpp>
  <tbb/blocked_range.h>
  <tbb/enumerable_thread_specific.h>
  <tbb/parallel_for.h>
  <algorithm>
  <cmath>
  <cstdint>
  <filesystem>
  <functional>
  <map>
  <memory>
  <string>
  <vector>)

if(FLYOVER_PCH)
  set(FLYOVER_PCH_SOURCE "${CMAKE_CURRENT_BINARY_DIR}/flyover_pch.cpp")
  file(WRITE "${FLYOVER_PCH_SOURCE}.in" "// the translation unit that builds the precompiled header\n")
  configure_file("${FLYOVER_PCH_SOURCE}.in" "${FLYOVER_PCH_SOURCE}" COPYONLY)
  add_library(flyover_pch OBJECT "${FLYOVER_PCH_SOURCE}")
  target_compile_features(flyover_pch PRIVATE cxx_std_17)
  target_link_libraries(flyover_pch PRIVATE OpenVDB::openvdb TBB::tbb nlohmann_json::nlohmann_json)
  target_precompile_headers(flyover_pch PRIVATE ${FLYOVER_PCH_HEADERS})
endif()

# Lets `target` reuse the precompiled headers (a no-op with FLYOVER_PCH=OFF). TEST: the ones
# with GoogleTest's header too.
function(flyover_use_pch target)
  cmake_parse_arguments(ARG "TEST" "" "" ${ARGN})
  if(NOT FLYOVER_PCH)
    return()
  endif()
  if(ARG_TEST)
    if(NOT TARGET flyover_test_pch)
      add_library(flyover_test_pch OBJECT "${FLYOVER_PCH_SOURCE}")
      target_compile_features(flyover_test_pch PRIVATE cxx_std_17)
      target_compile_options(flyover_test_pch PRIVATE ${FLYOVER_TEST_OPTIMIZE})
      target_link_libraries(flyover_test_pch PRIVATE OpenVDB::openvdb TBB::tbb nlohmann_json::nlohmann_json GTest::gtest)
      target_precompile_headers(flyover_test_pch PRIVATE ${FLYOVER_PCH_HEADERS} <gtest/gtest.h>)
    endif()
    target_precompile_headers(${target} REUSE_FROM flyover_test_pch)
  else()
    target_precompile_headers(${target} REUSE_FROM flyover_pch)
  endif()
endfunction()
