# One short libFuzzer run, as a ctest test (tests/fuzz/CMakeLists.txt):
#   cmake -DFUZZER=<exe> -DSEEDS=<tests/fuzz/corpus/NAME> -DWORK_DIR=<build dir>
#         -DSECONDS=<n> -P run_fuzzer.cmake
# Copies the seeds to WORK_DIR/corpus (the committed corpus is never written),
# fuzzes for SECONDS (the environment variable HAPTICPD_FUZZ_SECONDS overrides
# it) and fails if the fuzzer stops early: a crash, sanitizer report, leak,
# hang (10 s on one input) or out-of-memory (2 GB); the input that did it is
# written to WORK_DIR/artifacts/ and named in the output.
foreach(var FUZZER SEEDS WORK_DIR SECONDS)
  if(NOT DEFINED ${var})
    message(FATAL_ERROR "run_fuzzer.cmake: -D${var}=... is missing")
  endif()
endforeach()
if(DEFINED ENV{HAPTICPD_FUZZ_SECONDS} AND NOT "$ENV{HAPTICPD_FUZZ_SECONDS}" STREQUAL "")
  set(SECONDS "$ENV{HAPTICPD_FUZZ_SECONDS}")
endif()
if(NOT SECONDS MATCHES "^[1-9][0-9]*$")
  message(FATAL_ERROR "run_fuzzer.cmake: HAPTICPD_FUZZ_SECONDS '${SECONDS}' is not a positive whole number")
endif()

file(REMOVE_RECURSE "${WORK_DIR}")
file(MAKE_DIRECTORY "${WORK_DIR}/corpus" "${WORK_DIR}/artifacts")
file(GLOB seeds "${SEEDS}/*")
if(NOT seeds)
  message(FATAL_ERROR "run_fuzzer.cmake: no seeds in ${SEEDS}")
endif()
file(COPY ${seeds} DESTINATION "${WORK_DIR}/corpus")

execute_process(
  COMMAND "${FUZZER}" -max_total_time=${SECONDS} -timeout=10 -rss_limit_mb=2048
          -print_final_stats=1 "-artifact_prefix=${WORK_DIR}/artifacts/" "${WORK_DIR}/corpus"
  RESULT_VARIABLE rc)

file(GLOB found "${WORK_DIR}/artifacts/*")
if(NOT rc EQUAL 0 OR found)
  set(msg "${FUZZER} failed (exit ${rc}) after at most ${SECONDS} s.")
  foreach(f ${found})
    string(APPEND msg "\n  reproducer: ${f}")
  endforeach()
  string(APPEND msg "\n  Replay one with: ${FUZZER} <reproducer>; if the bug is ours, fix it and copy"
                    " the reproducer into ${SEEDS}/ so fuzz_replay_tests replays it.")
  message(FATAL_ERROR "${msg}")
endif()
