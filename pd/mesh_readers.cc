#include "pd/mesh_readers.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>

#include "pd/mesh.h"

namespace hapticpd::pd::internal {

std::string Printable(std::string_view text, std::size_t max_chars) {
  std::string s(text.substr(0, max_chars));
  for (char& c : s) {
    if (c < 0x20 || c > 0x7e) c = '?';
  }
  if (text.size() > max_chars) s += "...";
  return s;
}

bool Tokens::Next(std::string_view* tok) {
  const std::size_t b = rest_.find_first_not_of(kSpace);
  if (b == std::string_view::npos) {
    rest_ = {};
    return false;
  }
  rest_.remove_prefix(b);
  const std::size_t e = std::min(rest_.find_first_of(kSpace), rest_.size());
  *tok = rest_.substr(0, e);
  rest_.remove_prefix(e);
  return true;
}

std::size_t Tokens::Count() const {
  Tokens copy(*this);
  std::string_view t;
  std::size_t n = 0;
  while (copy.Next(&t)) ++n;
  return n;
}

namespace {

constexpr auto npos = std::string_view::npos;

// A token for an error message: at most 24 characters.
std::string Shown(std::string_view tok) { return Printable(tok, 24); }

// Lines of a text, numbered from 1 (or on from a given line).
class Lines {
 public:
  Lines(std::string_view text, std::size_t pos, std::size_t lineno)
      : text_(text), pos_(pos), lineno_(lineno) {}
  bool Next(std::string_view* line) {
    if (pos_ >= text_.size()) return false;
    std::size_t e = text_.find('\n', pos_);
    if (e == npos) e = text_.size();
    *line = text_.substr(pos_, e - pos_);
    pos_ = e + 1;
    ++lineno_;
    return true;
  }
  // The next line with something other than whitespace on it.
  bool NextNonBlank(std::string_view* line) {
    while (Next(line)) {
      if (line->find_first_not_of(kSpace) != npos) return true;
    }
    return false;
  }
  std::size_t lineno() const { return lineno_; }
  std::size_t pos() const { return std::min(pos_, text_.size()); }
  std::size_t remaining() const { return text_.size() - pos(); }

 private:
  std::string_view text_;
  std::size_t pos_;
  std::size_t lineno_;
};

bool IsDigit(char c) { return c >= '0' && c <= '9'; }

// A decimal number the way `istream >> float` reads one (what OpenMesh's
// readers did): [+-]digits[.digits][(e|E)[+-]digits], no hex, no inf/nan.
bool IsDecimal(std::string_view t) {
  std::size_t i = 0, digits = 0;
  if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
  while (i < t.size() && IsDigit(t[i])) ++i, ++digits;
  if (i < t.size() && t[i] == '.') {
    ++i;
    while (i < t.size() && IsDigit(t[i])) ++i, ++digits;
  }
  if (digits == 0) return false;
  if (i < t.size() && (t[i] == 'e' || t[i] == 'E')) {
    ++i;
    if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
    std::size_t exp_digits = 0;
    while (i < t.size() && IsDigit(t[i])) ++i, ++exp_digits;
    if (exp_digits == 0) return false;
  }
  return i == t.size();
}

bool IsInfOrNan(std::string_view t) {
  if (!t.empty() && (t[0] == '+' || t[0] == '-')) t.remove_prefix(1);
  std::string s(t.substr(0, 9));
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return t.size() <= 8 && (s == "inf" || s == "infinity" || s == "nan");
}

enum class Coord { kOk, kNotNumber, kNonFinite, kOutOfFloatRange };

// Parses a coordinate and rounds it to single precision exactly as
// `istream >> float` does (strtof; tiny values underflow to 0 or a
// subnormal, values beyond FLT_MAX are an error).
Coord ParseCoordinate(std::string_view t, double* out) {
  if (!IsDecimal(t)) return IsInfOrNan(t) ? Coord::kNonFinite : Coord::kNotNumber;
  const std::string s(t);
  // The C locale's '.' (nothing here calls setlocale); a parse that stops
  // early is not a number.
  char* end = nullptr;
  if (!std::isfinite(std::strtod(s.c_str(), &end))) return Coord::kNonFinite;
  if (end != s.c_str() + s.size()) return Coord::kNotNumber;
  const float f = std::strtof(s.c_str(), nullptr);
  if (!std::isfinite(f)) return Coord::kOutOfFloatRange;
  *out = f;
  return Coord::kOk;
}

// An integer token ([+-]digits). Saturates at +-LLONG_MAX on overflow (any
// such value is out of range wherever it is used).
bool ParseInteger(std::string_view t, long long* out) {
  std::size_t i = 0;
  bool negative = false;
  if (i < t.size() && (t[i] == '+' || t[i] == '-')) negative = t[i++] == '-';
  if (i == t.size()) return false;
  long long v = 0;
  for (; i < t.size(); ++i) {
    if (!IsDigit(t[i])) return false;
    const int d = t[i] - '0';
    v = v > (LLONG_MAX - d) / 10 ? LLONG_MAX : v * 10 + d;
  }
  *out = negative ? -v : v;
  return true;
}

std::string Number(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", x);
  return buf;
}

std::string Range(long long n) { return ", out of range [0, " + std::to_string(n) + ")"; }

// The message for a coordinate that did not parse; `what` names the vertex.
std::string CoordinateProblem(Coord c, const std::string& what, std::string_view tok) {
  switch (c) {
    case Coord::kNotNumber:
      return what + ": '" + Shown(tok) + "' is not a number";
    case Coord::kNonFinite:
      return what + " has a non-finite coordinate (" + Shown(tok) + ")";
    case Coord::kOutOfFloatRange:
      return what + " has a coordinate beyond single precision (" + Shown(tok) + ")";
    case Coord::kOk:
      break;
  }
  return what + ": bad coordinate";
}

}  // namespace

// ----------------------------------------------------------------------------
// OFF

PolygonSoup ReadOff(const std::string& path, std::string_view bytes) {
  Lines lines(bytes, 0, 0);
  std::string_view line;
  // The next line with content, '#' comments removed.
  auto next = [&]() -> bool {
    while (lines.Next(&line)) {
      const std::size_t hash = line.find('#');
      if (hash != npos) line = line.substr(0, hash);
      if (line.find_first_not_of(kSpace) != npos) return true;
    }
    return false;
  };
  auto where = [&]() { return path + ": line " + std::to_string(lines.lineno()) + ": "; };
  auto truncated = [&](long long promised, const char* what, long long held) {
    return MeshError(path + ": truncated after line " + std::to_string(lines.lineno()) +
                     ": the header promises " + std::to_string(promised) + " " + what +
                     ", the file holds " + std::to_string(held));
  };

  if (!next()) throw MeshError(path + ": file is empty");
  Tokens header(line);
  std::string_view magic;
  header.Next(&magic);
  if (magic.find("OFF") == npos) throw MeshError(where() + "missing OFF header");
  if (magic != "OFF") {
    // COFF/NOFF/4OFF/STOFF/OFF BINARY... carry colours, normals, a fourth
    // coordinate or binary data; we read plain OFF only.
    throw MeshError(where() + "OFF variant '" + Shown(magic) +
                    "' is not supported (plain OFF only)");
  }
  if (header.Count() != 0) {
    throw MeshError(where() + "element counts must be on the line after 'OFF'");
  }
  if (!next()) throw MeshError(path + ": truncated before the element counts");
  long long nv = -1, nf = -1, ne = -1;
  {
    Tokens counts(line);
    std::string_view a, b, c;
    if (counts.Count() != 3 || !counts.Next(&a) || !ParseInteger(a, &nv) || !counts.Next(&b) ||
        !ParseInteger(b, &nf) || !counts.Next(&c) || !ParseInteger(c, &ne) || nv < 0 || nf < 0) {
      throw MeshError(where() + "bad element counts (expected: vertices faces edges)");
    }
  }

  PolygonSoup soup;
  // Reserve no more than the rest of the file can hold ("0 0 0\n" per
  // vertex): a header count alone never decides an allocation.
  soup.points.reserve(static_cast<std::size_t>(
      std::min<long long>(nv, static_cast<long long>(lines.remaining() / 6))));
  for (long long v = 0; v < nv; ++v) {
    if (!next()) throw truncated(nv, "vertices", v);
    const std::string vertex = "vertex " + std::to_string(v);
    Tokens tokens(line);
    std::string_view tok;
    double p[3] = {0, 0, 0};
    int n = 0;
    while (tokens.Next(&tok)) {
      double x = 0;
      const Coord c = ParseCoordinate(tok, &x);
      if (c != Coord::kOk) throw MeshError(where() + CoordinateProblem(c, vertex, tok));
      if (n < 3) p[n] = x;
      ++n;
    }
    if (n != 3) {
      throw MeshError(where() + vertex + " has " + std::to_string(n) + " numbers, expected 3");
    }
    soup.points.emplace_back(p[0], p[1], p[2]);
  }
  for (long long f = 0; f < nf; ++f) {
    if (!next()) throw truncated(nf, "faces", f);
    const std::string face = "face " + std::to_string(f);
    Tokens tokens(line);
    std::string_view tok;
    long long count = 0;
    tokens.Next(&tok);
    if (!ParseInteger(tok, &count)) {
      throw MeshError(where() + face + ": vertex count '" + Shown(tok) + "' is not an integer");
    }
    if (count < 3) {
      throw MeshError(where() + face + " has " + std::to_string(count) +
                      " vertices, needs at least 3");
    }
    for (long long k = 0; k < count; ++k) {
      long long idx = -1;
      if (!tokens.Next(&tok)) {
        throw MeshError(where() + face + " lists " + std::to_string(k) +
                        " vertex indices, its count says " + std::to_string(count));
      }
      if (!ParseInteger(tok, &idx)) {
        throw MeshError(where() + face + ": vertex index '" + Shown(tok) + "' is not an integer");
      }
      if (idx < 0 || idx >= nv) {
        throw MeshError(where() + face + " refers to vertex " + Shown(tok) + Range(nv));
      }
      soup.corners.push_back(static_cast<Index>(idx));
    }
    // An optional colour may follow: a colour-map index or 3-4 components.
    int extra = 0;
    while (tokens.Next(&tok)) {
      if (!IsDecimal(tok)) {
        throw MeshError(where() + face + " has '" + Shown(tok) + "' after its " +
                        std::to_string(count) +
                        " vertex indices (expected at most a colour: 1 to 4 numbers)");
      }
      ++extra;
    }
    if (extra > 4) {
      throw MeshError(where() + face + " has " + std::to_string(extra) + " numbers after its " +
                      std::to_string(count) +
                      " vertex indices (expected at most a colour: 1 to 4 numbers)");
    }
    soup.EndFace();
  }
  if (next()) {
    throw MeshError(where() + "more data after the " + std::to_string(nv) + " vertices and " +
                    std::to_string(nf) + " faces the header promises");
  }
  return soup;
}

// ----------------------------------------------------------------------------
// PLY

namespace {

enum class Kind { kSigned, kUnsigned, kFloat };

struct Scalar {
  Kind kind = Kind::kSigned;
  int size = 0;  // bytes, 0 = unknown type
};

Scalar ScalarType(std::string_view name) {
  if (name == "char" || name == "int8") return {Kind::kSigned, 1};
  if (name == "uchar" || name == "uint8") return {Kind::kUnsigned, 1};
  if (name == "short" || name == "int16") return {Kind::kSigned, 2};
  if (name == "ushort" || name == "uint16") return {Kind::kUnsigned, 2};
  if (name == "int" || name == "int32") return {Kind::kSigned, 4};
  if (name == "uint" || name == "uint32") return {Kind::kUnsigned, 4};
  if (name == "float" || name == "float32") return {Kind::kFloat, 4};
  if (name == "double" || name == "float64") return {Kind::kFloat, 8};
  return {};
}

enum class Role { kSkip, kX, kY, kZ, kIndices };

struct Property {
  std::string name;
  Scalar value;
  bool list = false;
  Scalar count;  // list only
  Role role = Role::kSkip;
};

struct Element {
  std::string name;
  long long count = 0;
  std::vector<Property> properties;
  std::size_t line = 0;  // header line, for messages
};

enum class Format { kAscii, kBinaryLittle, kBinaryBig };

struct PlyHeader {
  Format format = Format::kAscii;
  std::vector<Element> elements;
  std::size_t body = 0;        // byte offset of the body
  std::size_t body_line = 0;   // number of the end_header line
  long long num_vertices = 0;  // the vertex element's count
};

PlyHeader ParsePlyHeader(const std::string& path, std::string_view bytes) {
  const std::string bad = path + ": not a valid PLY: ";
  Lines lines(bytes, 0, 0);
  std::string_view line;
  auto at = [&]() { return bad + "line " + std::to_string(lines.lineno()) + ": "; };
  std::string_view magic;
  if (!lines.Next(&line) || (Tokens(line).Next(&magic), magic != "ply") ||
      Tokens(line).Count() != 1) {
    throw MeshError(bad + "missing the 'ply' magic line");
  }
  PlyHeader h;
  bool have_format = false;
  while (lines.Next(&line)) {
    if (line == "end_header" || line == "end_header\r") {
      if (!have_format) throw MeshError(bad + "no 'format' line before end_header");
      h.body = lines.pos();
      h.body_line = lines.lineno();
      const Element* vertex = nullptr;
      const Element* face = nullptr;
      for (const Element& e : h.elements) {
        const Element** slot = e.name == "vertex" ? &vertex : e.name == "face" ? &face : nullptr;
        if (slot == nullptr) continue;
        if (*slot != nullptr) {
          throw MeshError(bad + "line " + std::to_string(e.line) + ": a second '" + e.name +
                          "' element");
        }
        *slot = &e;
      }
      if (vertex == nullptr) throw MeshError(bad + "the header declares no vertex element");
      for (Role r : {Role::kX, Role::kY, Role::kZ}) {
        if (std::none_of(vertex->properties.begin(), vertex->properties.end(),
                         [r](const Property& p) { return p.role == r; })) {
          throw MeshError(bad + "element vertex has no '" +
                          std::string(r == Role::kX   ? "x"
                                      : r == Role::kY ? "y"
                                                      : "z") +
                          "' property");
        }
      }
      if (face != nullptr &&
          std::none_of(face->properties.begin(), face->properties.end(),
                       [](const Property& p) { return p.role == Role::kIndices; })) {
        throw MeshError(bad +
                        "element face has no 'list <count type> <index type> "
                        "vertex_indices' property");
      }
      h.num_vertices = vertex->count;
      return h;
    }
    Tokens words(line);
    std::string_view keyword;
    words.Next(&keyword);
    // Anything outside this vocabulary is rejected (OpenMesh's header parser
    // looped forever on it; the messages are the ones its pre-scan gave).
    if (keyword == "format") {
      std::string_view name, version;
      words.Next(&name);
      words.Next(&version);
      if (name == "ascii") {
        h.format = Format::kAscii;
      } else if (name == "binary_little_endian") {
        h.format = Format::kBinaryLittle;
      } else if (name == "binary_big_endian") {
        h.format = Format::kBinaryBig;
      } else {
        version = {};
      }
      if (version != "1.0" || words.Count() != 0) {
        throw MeshError(at() +
                        "expected 'format ascii|binary_little_endian|binary_big_endian 1.0'");
      }
      have_format = true;
      continue;
    }
    if (keyword.empty() || keyword == "comment" || keyword == "obj_info") continue;
    if (keyword == "element") {
      std::string_view name, count_tok;
      long long count = 0;
      if (!words.Next(&name) || !words.Next(&count_tok) || words.Count() != 0 ||
          !ParseInteger(count_tok, &count)) {
        throw MeshError(at() + "expected 'element NAME COUNT'");
      }
      if (count < 0 || static_cast<unsigned long long>(count) > bytes.size()) {
        throw MeshError(bad + "element " + std::string(name) + " count " + std::to_string(count) +
                        " is more than a file of " + std::to_string(bytes.size()) +
                        " bytes can hold");
      }
      h.elements.push_back({std::string(name), count, {}, lines.lineno()});
      continue;
    }
    if (keyword == "property") {
      if (h.elements.empty()) throw MeshError(at() + "property before any element");
      std::string_view t, t2, name;
      words.Next(&t);
      Property p;
      p.list = t == "list";
      if (p.list) {
        words.Next(&t2);
        p.count = ScalarType(t2);
        words.Next(&t);
      }
      p.value = ScalarType(t);
      words.Next(&name);
      if (p.value.size == 0 || (p.list && p.count.size == 0) || name.empty() ||
          words.Count() != 0) {
        throw MeshError(at() + "expected 'property TYPE NAME' or 'property list TYPE TYPE NAME'");
      }
      p.name = std::string(name);
      Element& e = h.elements.back();
      if (p.list && p.count.kind == Kind::kFloat) {
        throw MeshError(at() + "list count type '" + std::string(t2) + "' is not an integer type");
      }
      if (e.name == "vertex" && (name == "x" || name == "y" || name == "z")) {
        if (p.list) throw MeshError(at() + "vertex coordinate '" + p.name + "' is a list");
        const Role r = name == "x" ? Role::kX : name == "y" ? Role::kY : Role::kZ;
        // A repeated coordinate is skipped; the first one counts.
        const bool seen = std::any_of(e.properties.begin(), e.properties.end(),
                                      [r](const Property& q) { return q.role == r; });
        if (!seen) p.role = r;
      }
      if (e.name == "face" && (name == "vertex_indices" || name == "vertex_index")) {
        if (!p.list) throw MeshError(at() + "face property '" + p.name + "' is not a list");
        if (p.value.kind == Kind::kFloat) {
          throw MeshError(at() + "vertex index type '" + std::string(t) +
                          "' is not an integer type");
        }
        const bool seen = std::any_of(e.properties.begin(), e.properties.end(),
                                      [](const Property& q) { return q.role == Role::kIndices; });
        if (!seen) p.role = Role::kIndices;
      }
      e.properties.push_back(std::move(p));
      continue;
    }
    throw MeshError(at() + "unknown header keyword '" + Shown(keyword) + "'");
  }
  throw MeshError(bad + "the header has no end_header line");
}

// Smallest number of body bytes one record of `e` takes.
std::size_t MinRecordBytes(const Element& e, bool ascii) {
  std::size_t n = 0;
  for (const Property& p : e.properties) {
    n += ascii ? 2 : static_cast<std::size_t>(p.list ? p.count.size : p.value.size);
  }
  return std::max<std::size_t>(n, 1);
}

// Adds one face's corner to the soup after the range check.
void CheckedCorner(PolygonSoup* soup, long long idx, long long nv, const std::string& where,
                   const std::string& what, const std::string& shown) {
  if (idx < 0 || idx >= nv)
    throw MeshError(where + what + " refers to vertex " + shown + Range(nv));
  soup->corners.push_back(static_cast<Index>(idx));
}

void ReadPlyAscii(const std::string& path, std::string_view bytes, const PlyHeader& h,
                  PolygonSoup* soup) {
  Lines lines(bytes, h.body, h.body_line);
  std::string_view line;
  auto where = [&]() { return path + ": line " + std::to_string(lines.lineno()) + ": "; };
  for (const Element& e : h.elements) {
    const bool is_vertex = e.name == "vertex";
    if (is_vertex) {
      soup->points.reserve(static_cast<std::size_t>(std::min<long long>(
          e.count, static_cast<long long>(lines.remaining() / MinRecordBytes(e, true)))));
    }
    for (long long i = 0; i < e.count; ++i) {
      if (!lines.NextNonBlank(&line)) {
        throw MeshError(path + ": truncated after line " + std::to_string(lines.lineno()) +
                        ": the header promises " + std::to_string(e.count) + " " + Shown(e.name) +
                        " elements, the file holds " + std::to_string(i));
      }
      const std::string what = Shown(e.name) + " " + std::to_string(i);
      Tokens tokens(line);
      const std::size_t total = tokens.Count();
      std::size_t used = 0;
      // Runs out of values: `more` more are needed for the property at hand.
      auto need = [&](std::size_t p, std::size_t more, std::string_view* tok) {
        if (tokens.Next(tok)) {
          ++used;
          return;
        }
        std::size_t expected = used + more;
        bool at_least = false;
        for (std::size_t q = p + 1; q < e.properties.size(); ++q) {
          ++expected;
          at_least = at_least || e.properties[q].list;
        }
        throw MeshError(where() + what + " has " + std::to_string(total) + " values, expected " +
                        (at_least ? "at least " : "") + std::to_string(expected));
      };
      double xyz[3] = {0, 0, 0};
      std::string_view tok;
      for (std::size_t p = 0; p < e.properties.size(); ++p) {
        const Property& prop = e.properties[p];
        if (!prop.list) {
          need(p, 1, &tok);
          if (prop.role == Role::kX || prop.role == Role::kY || prop.role == Role::kZ) {
            const int k = prop.role == Role::kX ? 0 : prop.role == Role::kY ? 1 : 2;
            const Coord c = ParseCoordinate(tok, &xyz[k]);
            if (c != Coord::kOk) throw MeshError(where() + CoordinateProblem(c, what, tok));
          } else if (!IsDecimal(tok) && !IsInfOrNan(tok)) {
            throw MeshError(where() + what + ": '" + Shown(tok) + "' (property " +
                            Shown(prop.name) + ") is not a number");
          }
          continue;
        }
        need(p, 1, &tok);
        long long n = 0;
        if (!ParseInteger(tok, &n) || n < 0) {
          throw MeshError(where() + what + ": list length '" + Shown(tok) + "' (property " +
                          Shown(prop.name) + ") is not a non-negative integer");
        }
        if (prop.role == Role::kIndices && n < 3) {
          throw MeshError(where() + what + " has " + std::to_string(n) +
                          " vertices, needs at least 3");
        }
        // n is bounded by the tokens on this line: `need` throws first.
        for (long long k = 0; k < n; ++k) {
          need(p, static_cast<std::size_t>(std::min<long long>(n - k, INT_MAX)), &tok);
          long long v = 0;
          if (prop.role == Role::kIndices) {
            if (!ParseInteger(tok, &v)) {
              throw MeshError(where() + what + ": vertex index '" + Shown(tok) +
                              "' is not an integer");
            }
            CheckedCorner(soup, v, h.num_vertices, where(), what, Shown(tok));
          } else if (!IsDecimal(tok) && !IsInfOrNan(tok)) {
            throw MeshError(where() + what + ": '" + Shown(tok) + "' (property " +
                            Shown(prop.name) + ") is not a number");
          }
        }
        if (prop.role == Role::kIndices) soup->EndFace();
      }
      if (used != total) {
        throw MeshError(where() + what + " has " + std::to_string(total) + " values, expected " +
                        std::to_string(used));
      }
      if (is_vertex) soup->points.emplace_back(xyz[0], xyz[1], xyz[2]);
    }
  }
  if (lines.NextNonBlank(&line)) {
    throw MeshError(where() + "more data after the elements the header declares");
  }
}

void ReadPlyBinary(const std::string& path, std::string_view bytes, const PlyHeader& h,
                   PolygonSoup* soup) {
  const bool big = h.format == Format::kBinaryBig;
  std::size_t pos = h.body;
  auto where = [&](std::size_t at) { return path + ": byte " + std::to_string(at) + ": "; };
  // Reads one scalar; false at the end of the file.
  auto read = [&](Scalar s, double* real, long long* integer) -> bool {
    if (bytes.size() - pos < static_cast<std::size_t>(s.size)) return false;
    unsigned char b[8];
    std::memcpy(b, bytes.data() + pos, static_cast<std::size_t>(s.size));
    pos += static_cast<std::size_t>(s.size);
    if (big) std::reverse(b, b + s.size);  // to little endian
    std::uint64_t u = 0;
    for (int k = s.size - 1; k >= 0; --k) u = (u << 8) | b[k];
    if (s.kind == Kind::kFloat) {
      double d = 0;
      if (s.size == 4) {
        float f = 0;
        const auto u32 = static_cast<std::uint32_t>(u);
        std::memcpy(&f, &u32, 4);
        d = f;
      } else {
        std::memcpy(&d, &u, 8);
      }
      *real = d;
      *integer = std::isfinite(d) && d == std::trunc(d) && std::fabs(d) < 9e18
                     ? static_cast<long long>(d)
                     : LLONG_MIN;
      return true;
    }
    long long v = static_cast<long long>(u);
    if (s.kind == Kind::kSigned && s.size < 8 && (u >> (8 * s.size - 1)) != 0) {
      v -= static_cast<long long>(1) << (8 * s.size);  // sign-extend
    }
    *integer = v;
    *real = static_cast<double>(v);
    return true;
  };
  for (const Element& e : h.elements) {
    const bool is_vertex = e.name == "vertex";
    if (is_vertex) {
      soup->points.reserve(static_cast<std::size_t>(std::min<long long>(
          e.count, static_cast<long long>((bytes.size() - pos) / MinRecordBytes(e, false)))));
    }
    for (long long i = 0; i < e.count; ++i) {
      const std::string what = Shown(e.name) + " " + std::to_string(i);
      const std::size_t start = pos;
      auto truncated = [&]() {
        return MeshError(path + ": truncated at byte " + std::to_string(bytes.size()) +
                         ": the header promises " + std::to_string(e.count) + " " + Shown(e.name) +
                         " elements, the file ends inside " + what);
      };
      double xyz[3] = {0, 0, 0};
      for (const Property& prop : e.properties) {
        double real = 0;
        long long integer = 0;
        if (!prop.list) {
          if (!read(prop.value, &real, &integer)) throw truncated();
          if (prop.role == Role::kX || prop.role == Role::kY || prop.role == Role::kZ) {
            if (!std::isfinite(real)) {
              throw MeshError(where(start) + what + " has a non-finite coordinate (" +
                              Number(real) + ")");
            }
            const float f = static_cast<float>(real);
            if (!std::isfinite(f)) {
              throw MeshError(where(start) + what + " has a coordinate beyond single precision (" +
                              Number(real) + ")");
            }
            xyz[prop.role == Role::kX ? 0 : prop.role == Role::kY ? 1 : 2] = f;
          }
          continue;
        }
        const std::size_t list_at = pos;
        if (!read(prop.count, &real, &integer)) throw truncated();
        if (integer < 0) {
          throw MeshError(where(list_at) + what + ": list " + Shown(prop.name) +
                          " has a negative length (" + std::to_string(integer) + ")");
        }
        const auto left = static_cast<unsigned long long>(bytes.size() - pos);
        if (static_cast<unsigned long long>(integer) >
            left / static_cast<unsigned>(prop.value.size)) {
          throw MeshError(where(list_at) + what + ": list " + Shown(prop.name) + " of " +
                          std::to_string(integer) + " entries runs past the end of the file (" +
                          std::to_string(left) + " bytes left)");
        }
        if (prop.role != Role::kIndices) {
          pos += static_cast<std::size_t>(integer) * static_cast<std::size_t>(prop.value.size);
          continue;
        }
        if (integer < 3) {
          throw MeshError(where(list_at) + what + " has " + std::to_string(integer) +
                          " vertices, needs at least 3");
        }
        for (long long k = 0; k < integer; ++k) {
          const std::size_t at = pos;
          long long idx = 0;
          read(prop.value, &real, &idx);  // in the file: checked above
          CheckedCorner(soup, idx, h.num_vertices, where(at), what, std::to_string(idx));
        }
        soup->EndFace();
      }
      if (is_vertex) soup->points.emplace_back(xyz[0], xyz[1], xyz[2]);
    }
  }
  // Bytes after the last element are ignored, as OpenMesh's reader did.
}

}  // namespace

PolygonSoup ReadPly(const std::string& path, std::string_view bytes) {
  const PlyHeader h = ParsePlyHeader(path, bytes);
  PolygonSoup soup;
  if (h.format == Format::kAscii) {
    ReadPlyAscii(path, bytes, h, &soup);
  } else {
    ReadPlyBinary(path, bytes, h, &soup);
  }
  return soup;
}

}  // namespace hapticpd::pd::internal
