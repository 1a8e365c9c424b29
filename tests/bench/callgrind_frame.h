// Per-frame instruction counts under callgrind: a CallgrindFrame around one
// PD call makes callgrind write that call's costs to a dump of their own,
// labelled "<label> <frame>". tests/bench/callgrind_frames.py runs a
// benchmark so (callgrind with --collect-atstart=no) and reads the dumps.
// Outside valgrind (or without its headers) it does nothing.
#pragma once

#include <cstddef>
#include <string>

#if __has_include(<valgrind/callgrind.h>)
#include <valgrind/callgrind.h>
#define HAPTICPD_CALLGRIND_FRAMES 1
#endif

namespace hapticpd::bench {

class CallgrindFrame {
 public:
  CallgrindFrame(const char* label, std::size_t frame) {
#ifdef HAPTICPD_CALLGRIND_FRAMES
    if (RUNNING_ON_VALGRIND) {
      label_ = std::string(label) + " " + std::to_string(frame);
      CALLGRIND_ZERO_STATS;
      CALLGRIND_TOGGLE_COLLECT;
    }
#else
    (void)label;
    (void)frame;
#endif
  }
  ~CallgrindFrame() {
#ifdef HAPTICPD_CALLGRIND_FRAMES
    if (!label_.empty()) {
      CALLGRIND_TOGGLE_COLLECT;
      CALLGRIND_DUMP_STATS_AT(label_.c_str());
    }
#endif
  }
  CallgrindFrame(const CallgrindFrame&) = delete;
  CallgrindFrame& operator=(const CallgrindFrame&) = delete;

 private:
  std::string label_;
};

}  // namespace hapticpd::bench
