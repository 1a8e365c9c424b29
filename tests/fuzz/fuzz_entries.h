// Entry points shared by the libFuzzer targets (tests/fuzz/fuzz_*.cc, built
// by the `fuzz` preset) and the corpus replay test of the normal suite
// (tests/fuzz/corpus_replay_test.cc). Each takes arbitrary bytes, runs them
// through the same code the server and CLI run on user input, and aborts if
// an invariant of the answer is broken (a crash, sanitizer report or
// uncaught exception is a finding too). None of them may throw.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace hapticpd::fuzz {

/// Mesh import of one format ("obj", "stl", "ply", "off") through the
/// server's upload path (MeshFromBytes, i.e. pd::LoadMesh on a private file).
void MeshImport(const std::string& format, const std::uint8_t* data, std::size_t size);

/// Scene-file parsing (server::ParseSceneJson) of the bytes as JSON text.
void SceneFile(const std::uint8_t* data, std::size_t size);

/// Server request validation: the bytes parsed as each request message the
/// services validate (AddBodyRequest, MoveBodyRequest, CreateSceneRequest,
/// Hello), fed to the validation functions the services call.
void RequestValidation(const std::uint8_t* data, std::size_t size);

/// Every target's name and entry, for the replay test.
struct Target {
  std::string name;  // the corpus folder under tests/fuzz/corpus/
  void (*run)(const std::uint8_t*, std::size_t);
};
std::vector<Target> Targets();

}  // namespace hapticpd::fuzz
