// Our own readers for OFF and PLY (ASCII and binary) bodies, used by
// pd::LoadMesh instead of OpenMesh's, whose stream-based parsing trusts the
// header counts: a body that does not match its header made them allocate
// gigabytes (fuzzer finds; tests/README.md, "Fuzzing"). These readers allocate
// only for what the file actually holds, so memory is O(file size), and name
// the line (or byte offset) and the problem on any mismatch.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "pd/types.h"

namespace hapticpd::pd::internal {

/// A polygon soup as a file lists it. Coordinates are rounded to single
/// precision, as OpenMesh's readers (still used for OBJ and STL) do, so a mesh
/// gives the same vertices in every format. Faces are stored back to back:
/// face f is corners[face_begin(f), face_end[f]).
struct PolygonSoup {
  std::vector<Vec3> points;
  std::vector<Index> corners;
  std::vector<std::size_t> face_end;

  std::size_t num_faces() const { return face_end.size(); }
  std::size_t face_begin(std::size_t f) const { return f == 0 ? 0 : face_end[f - 1]; }
  void EndFace() { face_end.push_back(corners.size()); }
};

/// `text` for an error message: bytes outside printable ASCII shown as '?',
/// cut after `max_chars` characters (then "..." is appended).
std::string Printable(std::string_view text, std::size_t max_chars = std::string_view::npos);

/// White space between tokens of a text mesh line (as OpenMesh's readers
/// split them with `>>`; lines come without their '\n').
inline constexpr std::string_view kSpace = " \t\r\v\f";

/// Whitespace-separated tokens of one line, without allocating.
class Tokens {
 public:
  explicit Tokens(std::string_view s) : rest_(s) {}
  bool Next(std::string_view* tok);
  std::size_t Count() const;
  /// What follows the last token returned.
  std::string_view rest() const { return rest_; }

 private:
  std::string_view rest_;
};

/// Parses a plain ASCII OFF file ("OFF", counts on the next line, one vertex
/// "x y z" per line, one face "n i0 .. i(n-1) [colour]" per line, '#'
/// comments). Every face has >= 3 indices, all in range. Throws MeshError
/// "<path>: line N: <problem>" on anything else, including the variants
/// (COFF, NOFF, 4OFF, OFF BINARY, ...), which are not supported.
PolygonSoup ReadOff(const std::string& path, std::string_view bytes);

/// Parses a PLY file (format ascii, binary_little_endian or
/// binary_big_endian 1.0): the vertex element's x, y, z (any scalar type),
/// the face element's `list <count> <index> vertex_indices` (or
/// vertex_index); every other property and element is skipped by its
/// declared layout. Every face has >= 3 indices, all in range. Throws
/// MeshError "<path>: not a valid PLY: ..." on a bad header and
/// "<path>: line N: ..." (ASCII) or "<path>: byte N: ..." (binary) on a body
/// that does not match it.
PolygonSoup ReadPly(const std::string& path, std::string_view bytes);

}  // namespace hapticpd::pd::internal
