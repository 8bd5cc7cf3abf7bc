# Helpers that declare every library, executable and test of the project the same way.
#
#   picking_library(NAME <name> SRCS <files...> [DEPS <targets...>]
#                   [PRIVATE_DEPS <targets...>])
#     -> target picking_<name>, alias picking::<name>. Public include root is the
#        repository root, so headers are included as "libs/geometry/pose.h".
#        DEPS (PUBLIC): every library a header of the target includes that other targets
#        include too; PRIVATE_DEPS: what only its .cc files (and headers only they include)
#        need. Each library a file includes is declared, even when another dependency
#        brings it already.
#   picking_executable(NAME <exe> SRCS <files...> [DEPS <targets...>])
#     -> build/bin/<exe>
#   picking_test(NAME <name> SRCS <files...> [DEPS <targets...>] [LABELS <labels...>]
#                [TIMEOUT <s>])
#     -> a GoogleTest binary registered with CTest (tests run from the build dir; the
#        PICKING_SOURCE_DIR, PICKING_BIN_DIR and PICKING_TEST_DATA_DIR definitions locate
#        data and server binaries).
#   picking_benchmark(NAME <name> SRCS <files...> [DEPS <targets...>])
#     -> build/bin/bench_<name> (Google Benchmark; not run by CTest).

function(picking_target_defaults target)
  if(CMAKE_CXX_COMPILER_ID MATCHES "GNU|Clang")
    target_compile_options(${target} PRIVATE -Wall -Wextra -Wno-unused-parameter)
  endif()
  # After dependency flags, so a dependency's -std=c++11 (fcl's pkg-config) cannot win.
  target_compile_features(${target} PUBLIC cxx_std_17)
  if(PICKING_SANITIZE)
    target_compile_options(${target} PRIVATE -fsanitize=${PICKING_SANITIZE}
                                             -fno-omit-frame-pointer)
    target_link_options(${target} PRIVATE -fsanitize=${PICKING_SANITIZE})
  endif()
endfunction()

function(picking_library)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS;PRIVATE_DEPS" ${ARGN})
  set(target picking_${ARG_NAME})
  add_library(${target} STATIC ${ARG_SRCS})
  add_library(picking::${ARG_NAME} ALIAS ${target})
  target_include_directories(${target} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${target} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
  picking_target_defaults(${target})
endfunction()

function(picking_executable)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SRCS})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_DEPS})
  picking_target_defaults(${ARG_NAME})
endfunction()

function(picking_test)
  if(NOT PICKING_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME;TIMEOUT" "SRCS;DEPS;LABELS" ${ARGN})
  set(target test_${ARG_NAME})
  add_executable(${target} ${ARG_SRCS})
  set_target_properties(${target} PROPERTIES RUNTIME_OUTPUT_DIRECTORY
                                             ${CMAKE_BINARY_DIR}/tests)
  target_link_libraries(${target} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gmock
                                          GTest::gtest_main)
  target_compile_definitions(${target} PRIVATE
    PICKING_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    PICKING_BIN_DIR="${CMAKE_BINARY_DIR}/bin"
    PICKING_TEST_DATA_DIR="${PROJECT_SOURCE_DIR}/tests/data"
    PICKING_DATA_DIR="${PROJECT_SOURCE_DIR}/data")
  picking_target_defaults(${target})
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 300)
  endif()
  if(NOT ARG_LABELS)
    set(ARG_LABELS unit)
  endif()
  add_test(NAME ${ARG_NAME} COMMAND ${target} --gtest_color=no)
  set_tests_properties(${ARG_NAME} PROPERTIES TIMEOUT ${ARG_TIMEOUT} LABELS "${ARG_LABELS}")
endfunction()

function(picking_benchmark)
  if(NOT PICKING_BUILD_BENCHMARKS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME" "SRCS;DEPS" ${ARGN})
  set(target bench_${ARG_NAME})
  add_executable(${target} ${ARG_SRCS})
  target_link_libraries(${target} PRIVATE ${ARG_DEPS} benchmark::benchmark)
  target_compile_definitions(${target} PRIVATE
    PICKING_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    PICKING_TEST_DATA_DIR="${PROJECT_SOURCE_DIR}/tests/data"
    PICKING_DATA_DIR="${PROJECT_SOURCE_DIR}/data")
  picking_target_defaults(${target})
endfunction()

# add_subdirectory() for every direct child of <dir> that has a CMakeLists.txt, sorted so
# the configure order is stable.
function(picking_add_components dir)
  file(GLOB children RELATIVE ${CMAKE_CURRENT_SOURCE_DIR}/${dir}
       ${CMAKE_CURRENT_SOURCE_DIR}/${dir}/*/CMakeLists.txt)
  list(SORT children)
  foreach(child ${children})
    get_filename_component(sub ${child} DIRECTORY)
    get_filename_component(abs ${CMAKE_CURRENT_SOURCE_DIR}/${dir}/${sub} ABSOLUTE)
    file(RELATIVE_PATH rel ${PROJECT_SOURCE_DIR} ${abs})
    # PICKING_ONLY (a regular expression over paths such as "libs/ur10") limits the build
    # to some components, for working on one part of the tree.
    if(PICKING_ONLY AND NOT rel MATCHES "${PICKING_ONLY}")
      continue()
    endif()
    add_subdirectory(${dir}/${sub})
  endforeach()
endfunction()
