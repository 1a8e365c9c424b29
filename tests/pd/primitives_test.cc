// Exact predicates and triangle primitives: convention and known-answer
// cases at several scales and offsets, exact references (integer
// determinants, an exact linear-programming feasibility test for triangle
// intersection), optimality certificates for the closest-point routines,
// dense sampling, and seeded random configurations (HAPTICPD_TEST_SEED,
// HAPTICPD_TEST_COUNT).
#include "pd/primitives.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "tests/test_util.h"

namespace hapticpd::pd::internal {
namespace {

using Tri = std::array<Vec3, 3>;
constexpr double kInf = std::numeric_limits<double>::infinity();

int Sgn(double x) { return (x > 0) - (x < 0); }

double Uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

Vec3 RandomVec(std::mt19937_64& rng, double lo, double hi) {
  return Vec3(Uniform(rng, lo, hi), Uniform(rng, lo, hi), Uniform(rng, lo, hi));
}

Mat3 RandomRotation(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0, 1);
  return Quat(n(rng), n(rng), n(rng), n(rng)).normalized().toRotationMatrix();
}

// A similarity x -> R (s x) + o under which known answers scale by s.
struct Frame {
  Mat3 R;
  double s;
  Vec3 o;
  Vec3 operator()(const Vec3& x) const { return R * (s * x) + o; }
  Vec3 Dir(const Vec3& v) const { return R * (s * v); }
  // Magnitude of the coordinates of a unit-sized configuration.
  double Magnitude() const { return s + o.cwiseAbs().maxCoeff(); }
};

// Scales 1e-3, 1, 1e3, without and with a 1e4 offset, axis-aligned and
// rotated.
std::vector<Frame> Frames() {
  std::mt19937_64 rng(7);
  std::vector<Frame> frames;
  for (double s : {1e-3, 1.0, 1e3}) {
    for (const Vec3& o : {Vec3(0, 0, 0), Vec3(1e4, -0.7e4, 0.3e4)}) {
      frames.push_back({Mat3::Identity(), s, o});
      frames.push_back({RandomRotation(rng), s, o});
    }
  }
  return frames;
}

// ---------------------------------------------------------------------------
// Exact integer references for the orientation predicates.

// x / 2^unit_exp as an integer; fails the test when that is not exact.
std::int64_t ToInt(double x, int unit_exp) {
  const double m = std::ldexp(x, -unit_exp);
  EXPECT_EQ(m, std::nearbyint(m)) << "not on the 2^" << unit_exp << " grid: " << x;
  EXPECT_LT(std::abs(m), 0x1p62);
  return static_cast<std::int64_t>(m);
}

using I128 = __int128;

// Sign of sum_i x_i * y_i for |x_i| < 2^60 and |y_i| < 2^122, three terms,
// without overflow: each y is split as hi * 2^64 + lo, lo in [0, 2^64).
int SignOfDot3(const std::int64_t x[3], const I128 y[3]) {
  I128 hi_sum = 0, lo_sum = 0;
  for (int i = 0; i < 3; ++i) {
    const I128 yhi = y[i] >> 64;  // arithmetic shift: floor
    const I128 ylo = y[i] - (yhi << 64);
    hi_sum += static_cast<I128>(x[i]) * yhi;
    lo_sum += static_cast<I128>(x[i]) * ylo;
  }
  const I128 carry = lo_sum >> 64;
  hi_sum += carry;
  lo_sum -= carry << 64;  // now in [0, 2^64)
  if (hi_sum != 0) return hi_sum > 0 ? 1 : -1;
  return lo_sum > 0 ? 1 : 0;
}

// Exact sign of det[a - d; b - d; c - d] for coordinates on the 2^unit_exp
// grid whose differences stay below 2^60 grid units.
int ReferenceOrient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, int unit_exp) {
  std::int64_t A[3], B[3], C[3];
  for (int k = 0; k < 3; ++k) {
    const std::int64_t dk = ToInt(d[k], unit_exp);
    A[k] = ToInt(a[k], unit_exp) - dk;
    B[k] = ToInt(b[k], unit_exp) - dk;
    C[k] = ToInt(c[k], unit_exp) - dk;
    EXPECT_LT(std::max({std::abs(A[k]), std::abs(B[k]), std::abs(C[k])}), std::int64_t{1} << 60);
  }
  // Expansion along the first row: A . (B x C).
  const I128 minors[3] = {static_cast<I128>(B[1]) * C[2] - static_cast<I128>(B[2]) * C[1],
                          static_cast<I128>(B[2]) * C[0] - static_cast<I128>(B[0]) * C[2],
                          static_cast<I128>(B[0]) * C[1] - static_cast<I128>(B[1]) * C[0]};
  return SignOfDot3(A, minors);
}

int ReferenceOrient2d(const Vec2& a, const Vec2& b, const Vec2& c, int unit_exp) {
  const I128 ax = ToInt(a.x(), unit_exp) - ToInt(c.x(), unit_exp);
  const I128 ay = ToInt(a.y(), unit_exp) - ToInt(c.y(), unit_exp);
  const I128 bx = ToInt(b.x(), unit_exp) - ToInt(c.x(), unit_exp);
  const I128 by = ToInt(b.y(), unit_exp) - ToInt(c.y(), unit_exp);
  const I128 det = ax * by - ay * bx;
  return (det > 0) - (det < 0);
}

double NaiveOrient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  return (a - d).dot((b - d).cross(c - d));
}

double NaiveOrient2d(const Vec2& a, const Vec2& b, const Vec2& c) {
  return (a.x() - c.x()) * (b.y() - c.y()) - (a.y() - c.y()) * (b.x() - c.x());
}

// A multiple of 2^-20 in [-32, 32]: on the 2^-53 grid with room to spare.
double GridCoord(std::mt19937_64& rng) {
  return std::ldexp(std::round(Uniform(rng, -32, 32) * 0x1p20), -20);
}

// ---------------------------------------------------------------------------
// Orientation predicates.

TEST(PrimitivesOrient, SignConventions) {
  const Vec3 o(0, 0, 0), x(1, 0, 0), y(0, 1, 0), z(0, 0, 1);
  // a, b, c counter-clockwise seen from +z (normal (b-a)x(c-a) = +z):
  // d below (-z) is positive, d above is negative.
  EXPECT_EQ(Orient3d(o, x, y, -z), 1.0);
  EXPECT_EQ(Orient3d(o, x, y, z), -1.0);
  EXPECT_EQ(Orient3d(o, x, y, Vec3(0.3, 0.2, 0)), 0.0);
  EXPECT_GT(Orient3d(o, y, x, z), 0.0);  // clockwise from +z: +z is "below"
  // det[a-d; b-d; c-d] literally.
  const Vec3 a(1, 2, 3), b(-2, 0.5, 1), c(0.25, -1, 2), d(0.5, 0.5, -1);
  Mat3 m;
  m.row(0) = a - d;
  m.row(1) = b - d;
  m.row(2) = c - d;
  EXPECT_NEAR(Orient3d(a, b, c, d), m.determinant(), 1e-12);

  EXPECT_EQ(Orient2d(Vec2(0, 0), Vec2(1, 0), Vec2(0, 1)), 1.0);   // counter-clockwise
  EXPECT_EQ(Orient2d(Vec2(0, 0), Vec2(0, 1), Vec2(1, 0)), -1.0);  // clockwise
  EXPECT_EQ(Orient2d(Vec2(0, 0), Vec2(1, 1), Vec2(3, 3)), 0.0);
}

TEST(PrimitivesOrient, PermutationAntisymmetry) {
  std::mt19937_64 rng(testing::TestSeed());
  for (int i = 0; i < 2000; ++i) {
    const Vec3 a = RandomVec(rng, -1, 1), b = RandomVec(rng, -1, 1), c = RandomVec(rng, -1, 1);
    // Nearly coplanar d, so some evaluations take the exact path.
    Vec3 d = a + Uniform(rng, 0, 1) * (b - a) + Uniform(rng, 0, 1) * (c - a);
    if (i % 2) d.z() = std::nextafter(d.z(), kInf);
    const int s = Sgn(Orient3d(a, b, c, d));
    EXPECT_EQ(Sgn(Orient3d(b, a, c, d)), -s);
    EXPECT_EQ(Sgn(Orient3d(a, c, b, d)), -s);
    EXPECT_EQ(Sgn(Orient3d(d, b, c, a)), -s);
    EXPECT_EQ(Sgn(Orient3d(b, c, a, d)), s);  // even permutation
    EXPECT_EQ(Sgn(Orient3d(b, a, d, c)), s);
  }
}

// Points on a plane, one of them moved by a few ulp: naive double evaluation
// gets the sign wrong, Orient3d must match an exact integer evaluation.
TEST(PrimitivesOrient, Orient3dExactOnNearlyCoplanarPoints) {
  std::mt19937_64 rng(testing::TestSeed() + 1);
  const int count = testing::TestCount(3000);
  int naive_wrong = 0, exact_zero = 0, checked = 0;
  for (int i = 0; i < count; ++i) {
    const Vec3 a(GridCoord(rng), GridCoord(rng), GridCoord(rng));
    const Vec3 b(GridCoord(rng), GridCoord(rng), GridCoord(rng));
    const Vec3 c(GridCoord(rng), GridCoord(rng), GridCoord(rng));
    const Vec3 n = (b - a).cross(c - a);
    if (std::abs(n.z()) < 1e-3 * n.norm() || std::abs(n.x()) < 1e-3 * n.norm()) continue;
    // d with x, y in [0.5, 1) (ulp 2^-53) and z on the plane, rounded to
    // the 2^-53 grid; then x moved by k ulp.
    Vec3 d(Uniform(rng, 0.5, 1), Uniform(rng, 0.5, 1), 0);
    const double z = a.z() - (n.x() * (d.x() - a.x()) + n.y() * (d.y() - a.y())) / n.z();
    if (std::abs(z) > 32) continue;  // keep the reference within 2^60 grid units
    d.z() = std::ldexp(std::round(std::ldexp(z, 53)), -53);
    for (int k = -3; k <= 3; ++k) {
      Vec3 dk = d;
      dk.x() += k * 0x1p-53;
      for (int e : {-30, 0, 30}) {  // exact power-of-two scalings keep the sign
        const Vec3 as = std::ldexp(1.0, e) * a, bs = std::ldexp(1.0, e) * b;
        const Vec3 cs = std::ldexp(1.0, e) * c, ds = std::ldexp(1.0, e) * dk;
        const int ref = ReferenceOrient3d(as, bs, cs, ds, e - 53);
        ASSERT_EQ(Sgn(Orient3d(as, bs, cs, ds)), ref) << "i=" << i << " k=" << k << " e=" << e;
        ASSERT_EQ(Sgn(Orient3d(ds, as, bs, cs)), -ref);
        naive_wrong += Sgn(NaiveOrient3d(as, bs, cs, ds)) != ref;
        exact_zero += ref == 0;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 10000);
  // The inputs really are beyond plain double arithmetic.
  EXPECT_GT(naive_wrong, checked / 20) << "naive wrong " << naive_wrong << " of " << checked;
  RecordProperty("naive_wrong", naive_wrong);
  RecordProperty("exact_zero", exact_zero);
}

TEST(PrimitivesOrient, Orient3dExactZeroOnCoplanarGridPoints) {
  std::mt19937_64 rng(testing::TestSeed() + 2);
  std::uniform_int_distribution<int> small(-8, 8);
  for (int i = 0; i < 2000; ++i) {
    const double unit = std::ldexp(1.0, small(rng) * 3);  // 2^-24 .. 2^24
    const Vec3 offset = (i % 2) ? Vec3(1e4, -3e4, 8192) : Vec3::Zero();
    auto g = [&]() {
      Vec3 v;
      for (int k = 0; k < 3; ++k) v[k] = small(rng) * unit;
      return v;
    };
    const Vec3 a = g(), e1 = g(), e2 = g();
    const Vec3 d = a + small(rng) * e1 + small(rng) * e2;  // exact: small integers
    // Exactly coplanar, including with the offset (all sums are exact).
    EXPECT_EQ(Orient3d(a + offset, a + e1 + offset, a + e2 + offset, d + offset), 0.0) << i;
  }
}

TEST(PrimitivesOrient, Orient2dClassicNearCollinear) {
  // Kettner et al., "Classroom examples of robustness problems": points on a
  // 256 x 256 ulp grid around (0.5, 0.5) against the line (12,12)-(24,24).
  const Vec2 q(12, 12), r(24, 24);
  int naive_wrong = 0;
  for (int i = 0; i < 256; ++i) {
    for (int j = 0; j < 256; ++j) {
      const Vec2 p(0.5 + i * 0x1p-53, 0.5 + j * 0x1p-53);
      const int ref = ReferenceOrient2d(p, q, r, -53);
      ASSERT_EQ(Sgn(Orient2d(p, q, r)), ref) << i << "," << j;
      ASSERT_EQ(Sgn(Orient2d(q, p, r)), -ref);
      ASSERT_EQ(Sgn(Orient2d(q, r, p)), ref);
      naive_wrong += Sgn(NaiveOrient2d(p, q, r)) != ref;
    }
  }
  EXPECT_GT(naive_wrong, 1000);
}

TEST(PrimitivesOrient, Orient2dExactOnNearlyCollinearPoints) {
  std::mt19937_64 rng(testing::TestSeed() + 3);
  int naive_wrong = 0, checked = 0;
  for (int i = 0; i < 3000; ++i) {
    const Vec2 a(GridCoord(rng), GridCoord(rng)), b(GridCoord(rng), GridCoord(rng));
    if (std::abs(b.y() - a.y()) < 1) continue;
    // c on line ab with y in [0.5, 1), x rounded to the 2^-53 grid.
    const double y = Uniform(rng, 0.5, 1);
    const double x = a.x() + (b.x() - a.x()) * (y - a.y()) / (b.y() - a.y());
    if (std::abs(x) > 32) continue;  // keep the reference within 2^60 grid units
    for (int k = -2; k <= 2; ++k) {
      const Vec2 c(std::ldexp(std::round(std::ldexp(x, 53)), -53), y + k * 0x1p-53);
      const int ref = ReferenceOrient2d(a, b, c, -53);
      ASSERT_EQ(Sgn(Orient2d(a, b, c)), ref);
      ASSERT_EQ(Sgn(Orient2d(c, a, b)), ref);
      naive_wrong += Sgn(NaiveOrient2d(a, b, c)) != ref;
      ++checked;
    }
  }
  EXPECT_GT(naive_wrong, checked / 20);
}

// ---------------------------------------------------------------------------
// Triangle intersection.

// Independent exact reference: the closed triangles intersect iff
//   sum_i l_i P_i = sum_j m_j Q_j,  sum l = sum m = 1,  l, m >= 0
// is feasible. A feasible system has a basic solution (support on linearly
// independent columns), so enumerate the 63 column subsets, solve exactly by
// Cramer's rule (fraction-free determinants in 128-bit integers) and check
// the remaining equations and the signs. Integer coordinates only.
I128 Det(I128 m[5][5], int n) {
  I128 sign = 1, prev = 1;
  for (int k = 0; k < n; ++k) {
    if (m[k][k] == 0) {
      int r = k + 1;
      while (r < n && m[r][k] == 0) ++r;
      if (r == n) return 0;
      for (int j = 0; j < n; ++j) std::swap(m[k][j], m[r][j]);
      sign = -sign;
    }
    for (int i = k + 1; i < n; ++i) {
      for (int j = k + 1; j < n; ++j) m[i][j] = (m[i][j] * m[k][k] - m[i][k] * m[k][j]) / prev;
    }
    prev = m[k][k];
  }
  return sign * m[n - 1][n - 1];
}

using ITri = std::array<std::array<int, 3>, 3>;

bool LpTrianglesIntersect(const ITri& P, const ITri& Q) {
  I128 A[5][6] = {};
  const I128 rhs[5] = {0, 0, 0, 1, 1};
  for (int i = 0; i < 3; ++i) {
    for (int r = 0; r < 3; ++r) {
      A[r][i] = P[i][r];
      A[r][3 + i] = -Q[i][r];
    }
    A[3][i] = 1;
    A[4][3 + i] = 1;
  }
  for (int mask = 1; mask < 64; ++mask) {
    int cols[6], k = 0;
    for (int j = 0; j < 6; ++j) {
      if (mask & (1 << j)) cols[k++] = j;
    }
    if (k > 5) continue;
    // Find k rows with a non-singular k x k block.
    for (int rmask = 0; rmask < 32; ++rmask) {
      if (__builtin_popcount(rmask) != k) continue;
      int rows[5], nr = 0;
      for (int r = 0; r < 5; ++r) {
        if (rmask & (1 << r)) rows[nr++] = r;
      }
      I128 m[5][5];
      for (int a = 0; a < k; ++a) {
        for (int b = 0; b < k; ++b) m[a][b] = A[rows[a]][cols[b]];
      }
      const I128 det = Det(m, k);
      if (det == 0) continue;
      // Independent columns: the solution, if any, is unique.
      I128 num[5];
      bool ok = true;
      for (int j = 0; j < k && ok; ++j) {
        for (int a = 0; a < k; ++a) {
          for (int b = 0; b < k; ++b) m[a][b] = b == j ? rhs[rows[a]] : A[rows[a]][cols[b]];
        }
        num[j] = Det(m, k);
        ok = (num[j] >= 0) == (det > 0) || num[j] == 0;  // x_j = num_j / det >= 0
      }
      for (int r = 0; r < 5 && ok; ++r) {
        I128 lhs = 0;
        for (int j = 0; j < k; ++j) lhs += A[r][cols[j]] * num[j];
        ok = lhs == rhs[r] * det;
      }
      if (ok) return true;
      break;
    }
  }
  return false;
}

// Exact rearrangements that cannot change whether two triangles meet.
Tri Permuted(const Tri& t, int perm) {
  static constexpr int kPerm[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1},
                                      {0, 2, 1}, {2, 1, 0}, {1, 0, 2}};
  return {t[kPerm[perm][0]], t[kPerm[perm][1]], t[kPerm[perm][2]]};
}

// An exactly representable similarity: axis permutation and sign flips,
// scaling by 2^e, and an offset. With the integer coordinates used here
// (|x| <= 8) and e >= -20, every result is exact.
struct ExactMap {
  int axes[3];
  double flip[3];
  int e;
  Vec3 offset;
  Vec3 operator()(const Vec3& x) const {
    Vec3 y;
    for (int k = 0; k < 3; ++k) y[k] = flip[k] * std::ldexp(x[axes[k]], e) + offset[k];
    return y;
  }
};

ExactMap RandomExactMap(std::mt19937_64& rng) {
  ExactMap m{{0, 1, 2}, {1, 1, 1}, 0, Vec3::Zero()};
  std::shuffle(m.axes, m.axes + 3, rng);
  for (double& f : m.flip) f = (rng() & 1) ? 1 : -1;
  m.e = std::uniform_int_distribution<int>(-20, 20)(rng);
  switch (rng() % 3) {
    case 0:
      break;
    case 1:
      m.offset = Vec3(1e4, -1e4, 8192);
      break;
    default:
      m.offset = Vec3(-3.0, 0.5, 1e4);
      break;
  }
  return m;
}

Tri Map(const ExactMap& m, const Tri& t) { return {m(t[0]), m(t[1]), m(t[2])}; }

Tri ToTri(const ITri& t) {
  Tri r;
  for (int i = 0; i < 3; ++i) r[i] = Vec3(t[i][0], t[i][1], t[i][2]);
  return r;
}

bool Intersect(const Tri& P, const Tri& Q) {
  return TrianglesIntersect(P[0], P[1], P[2], Q[0], Q[1], Q[2]);
}

// Checks `expected` for P, Q under vertex permutations, argument swap and a
// few exact maps.
void ExpectIntersect(const Tri& P, const Tri& Q, bool expected, std::mt19937_64& rng,
                     const char* what) {
  for (int perm = 0; perm < 6; ++perm) {
    ASSERT_EQ(Intersect(Permuted(P, perm), Permuted(Q, (perm + 1) % 6)), expected)
        << what << " perm " << perm;
    ASSERT_EQ(Intersect(Permuted(Q, perm), Permuted(P, (perm + 2) % 6)), expected)
        << what << " swapped, perm " << perm;
  }
  for (int i = 0; i < 4; ++i) {
    const ExactMap m = RandomExactMap(rng);
    ASSERT_EQ(Intersect(Map(m, P), Map(m, Q)), expected)
        << what << " mapped, e=" << m.e << " offset " << m.offset.transpose();
  }
}

TEST(PrimitivesTrianglesIntersect, KnownCases) {
  std::mt19937_64 rng(testing::TestSeed() + 10);
  const Tri base = {Vec3(0, 0, 0), Vec3(4, 0, 0), Vec3(0, 4, 0)};
  struct Case {
    const char* what;
    Tri q;
    bool expected;
  };
  const Case cases[] = {
      {"parallel plane above", {Vec3(0, 0, 1), Vec3(4, 0, 1), Vec3(0, 4, 1)}, false},
      {"coplanar overlapping", {Vec3(1, 1, 0), Vec3(5, 1, 0), Vec3(1, 5, 0)}, true},
      {"coplanar contained", {Vec3(1, 1, 0), Vec3(2, 1, 0), Vec3(1, 2, 0)}, true},
      {"coplanar containing", {Vec3(-1, -1, 0), Vec3(9, -1, 0), Vec3(-1, 9, 0)}, true},
      {"coplanar vertex on vertex", {Vec3(4, 0, 0), Vec3(6, 0, 0), Vec3(6, 2, 0)}, true},
      {"coplanar vertex on edge", {Vec3(2, 2, 0), Vec3(4, 4, 0), Vec3(3, 5, 0)}, true},
      {"coplanar shared edge", {Vec3(4, 0, 0), Vec3(0, 4, 0), Vec3(4, 4, 0)}, true},
      {"coplanar collinear edges overlapping",
       {Vec3(2, 0, 0), Vec3(6, 0, 0), Vec3(4, -2, 0)},
       true},
      {"coplanar disjoint across hypotenuse", {Vec3(3, 2, 0), Vec3(5, 2, 0), Vec3(3, 4, 0)}, false},
      {"coplanar disjoint beside vertex", {Vec3(5, 0, 0), Vec3(6, 0, 0), Vec3(5, 1, 0)}, false},
      {"piercing", {Vec3(1, 1, -1), Vec3(1, 1, 1), Vec3(8, 8, 0)}, true},
      {"vertex on face", {Vec3(1, 1, 0), Vec3(2, 1, 3), Vec3(1, 2, 3)}, true},
      {"vertex on edge", {Vec3(2, 0, 0), Vec3(2, -1, 3), Vec3(3, -1, 3)}, true},
      {"vertex on vertex", {Vec3(4, 0, 0), Vec3(5, 0, 3), Vec3(4, 1, 3)}, true},
      {"edge on edge crossing", {Vec3(2, -1, 0), Vec3(2, 1, 0), Vec3(2, 0, 3)}, true},
      {"edge in face", {Vec3(1, 1, 0), Vec3(2, 1, 0), Vec3(1, 1, 3)}, true},
      {"edge crossing face boundary", {Vec3(-1, 2, 0), Vec3(2, 2, 0), Vec3(-1, 2, 3)}, true},
      {"near miss below vertex", {Vec3(4, 0, 1), Vec3(5, 0, 1), Vec3(5, 1, -1)}, false},
      {"vertex just above face", {Vec3(1, 1, 1), Vec3(2, 1, 3), Vec3(1, 2, 3)}, false},
      {"segment piercing", {Vec3(1, 1, -1), Vec3(1, 1, 1), Vec3(1, 1, 0.5)}, true},
      {"segment touching face", {Vec3(1, 1, 0), Vec3(1, 1, 1), Vec3(1, 1, 2)}, true},
      {"segment above", {Vec3(1, 1, 1), Vec3(1, 1, 2), Vec3(1, 1, 3)}, false},
      {"segment in plane crossing edge", {Vec3(3, 3, 0), Vec3(1, 1, 0), Vec3(5, 5, 0)}, true},
      {"segment in plane outside", {Vec3(3, 3, 0), Vec3(5, 3, 0), Vec3(4, 3, 0)}, false},
      {"point on edge", {Vec3(2, 0, 0), Vec3(2, 0, 0), Vec3(2, 0, 0)}, true},
      {"point in plane outside", {Vec3(3, 3, 0), Vec3(3, 3, 0), Vec3(3, 3, 0)}, false},
      {"point off plane", {Vec3(1, 1, 1), Vec3(1, 1, 1), Vec3(1, 1, 1)}, false},
  };
  for (const Case& c : cases) ExpectIntersect(base, c.q, c.expected, rng, c.what);

  // Both degenerate.
  const Tri seg_x = {Vec3(0, 0, 0), Vec3(4, 0, 0), Vec3(2, 0, 0)};
  ExpectIntersect(seg_x, {Vec3(2, -1, 0), Vec3(2, 1, 0), Vec3(2, 1, 0)}, true, rng,
                  "segments crossing");
  ExpectIntersect(seg_x, {Vec3(2, -1, 1), Vec3(2, 1, 1), Vec3(2, 1, 1)}, false, rng,
                  "segments skew");
  ExpectIntersect(seg_x, {Vec3(3, 0, 0), Vec3(6, 0, 0), Vec3(5, 0, 0)}, true, rng,
                  "collinear overlap");
  ExpectIntersect(seg_x, {Vec3(4, 0, 0), Vec3(6, 0, 0), Vec3(5, 0, 0)}, true, rng,
                  "collinear touching");
  ExpectIntersect(seg_x, {Vec3(5, 0, 0), Vec3(6, 0, 0), Vec3(7, 0, 0)}, false, rng,
                  "collinear apart");
  ExpectIntersect(seg_x, {Vec3(1, 1, 0), Vec3(3, 1, 0), Vec3(2, 1, 0)}, false, rng,
                  "parallel apart");
  ExpectIntersect(seg_x, {Vec3(1, 0, 0), Vec3(1, 0, 0), Vec3(1, 0, 0)}, true, rng,
                  "point on segment");
  ExpectIntersect(seg_x, {Vec3(1, 0x1p-10, 0), Vec3(1, 0x1p-10, 0), Vec3(1, 0x1p-10, 0)}, false,
                  rng, "point slightly off segment");
  const Vec3 off(1, 1e-300, 0);
  EXPECT_FALSE(TrianglesIntersect(seg_x[0], seg_x[1], seg_x[2], off, off, off));
  EXPECT_FALSE(TrianglesIntersect(off, off, off, seg_x[0], seg_x[1], seg_x[2]));
  const Tri pt = {Vec3(1, 2, 3), Vec3(1, 2, 3), Vec3(1, 2, 3)};
  ExpectIntersect(pt, pt, true, rng, "same point");

  // Off by one ulp, at a large offset: only exact arithmetic gets these.
  const double z = std::nextafter(1e4, kInf);
  const Tri high = {Vec3(1, 1, z), Vec3(2, 1, 1e4 + 3), Vec3(1, 2, 1e4 + 3)};
  const Tri at = {Vec3(0, 0, 1e4), Vec3(4, 0, 1e4), Vec3(0, 4, 1e4)};
  EXPECT_FALSE(Intersect(at, high));
  EXPECT_FALSE(Intersect(high, at));
  const Tri touching = {Vec3(1, 1, 1e4), Vec3(2, 1, 1e4 + 3), Vec3(1, 2, 1e4 + 3)};
  EXPECT_TRUE(Intersect(at, touching));
  EXPECT_TRUE(Intersect(touching, at));
}

// Random triangles on a tiny integer grid (so coplanar, touching and
// degenerate configurations are common) against the exact LP reference.
TEST(PrimitivesTrianglesIntersect, MatchesExactReferenceOnIntegerGrid) {
  std::mt19937_64 rng(testing::TestSeed() + 11);
  const int count = testing::TestCount(3000);
  std::uniform_int_distribution<int> coord(0, 3);
  int hits = 0, degenerate = 0, coplanar = 0;
  for (int i = 0; i < count; ++i) {
    ITri P, Q;
    for (auto& v : P)
      for (int& x : v) x = coord(rng);
    for (auto& v : Q)
      for (int& x : v) x = coord(rng);
    // Bias a third of the pairs into one plane z = const.
    if (i % 3 == 0) {
      for (auto& v : P) v[2] = 1;
      for (auto& v : Q) v[2] = 1;
    }
    const bool expected = LpTrianglesIntersect(P, Q);
    const Tri p = ToTri(P), q = ToTri(Q);
    hits += expected;
    degenerate += (p[1] - p[0]).cross(p[2] - p[0]).squaredNorm() == 0;
    coplanar += Orient3d(p[0], p[1], p[2], q[0]) == 0 && Orient3d(p[0], p[1], p[2], q[1]) == 0 &&
                Orient3d(p[0], p[1], p[2], q[2]) == 0;
    ASSERT_EQ(Intersect(p, q), expected) << "pair " << i;
    ASSERT_EQ(Intersect(Permuted(q, i % 6), Permuted(p, (i / 6) % 6)), expected) << "pair " << i;
    const ExactMap m = RandomExactMap(rng);
    ASSERT_EQ(Intersect(Map(m, p), Map(m, q)), expected) << "pair " << i << " mapped";
  }
  // The reference must have produced both answers and many special cases.
  EXPECT_GT(hits, count / 5);
  EXPECT_LT(hits, count - count / 5);
  EXPECT_GT(degenerate, count / 50);
  EXPECT_GT(coplanar, count / 5);
}

// Separating-axis reference for two non-degenerate triangles in general
// position: the largest gap over the 11 candidate axes (> 0: disjoint).
double SeparatingGap(const Tri& P, const Tri& Q) {
  std::vector<Vec3> axes = {(P[1] - P[0]).cross(P[2] - P[0]), (Q[1] - Q[0]).cross(Q[2] - Q[0])};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      axes.push_back((P[(i + 1) % 3] - P[i]).cross(Q[(j + 1) % 3] - Q[j]));
    }
  }
  double gap = -kInf;
  for (const Vec3& a : axes) {
    if (a.norm() < 1e-6) continue;
    const Vec3 u = a.normalized();
    double p_lo = kInf, p_hi = -kInf, q_lo = kInf, q_hi = -kInf;
    for (const Vec3& v : P) {
      p_lo = std::min(p_lo, u.dot(v));
      p_hi = std::max(p_hi, u.dot(v));
    }
    for (const Vec3& v : Q) {
      q_lo = std::min(q_lo, u.dot(v));
      q_hi = std::max(q_hi, u.dot(v));
    }
    gap = std::max({gap, q_lo - p_hi, p_lo - q_hi});
  }
  return gap;
}

TEST(PrimitivesTrianglesIntersect, MatchesSeparatingAxesOnRandomTriangles) {
  std::mt19937_64 rng(testing::TestSeed() + 12);
  const int count = testing::TestCount(3000);
  int hits = 0, misses = 0;
  for (int i = 0; i < count; ++i) {
    const Vec3 c = RandomVec(rng, -0.6, 0.6);
    const Tri P = {RandomVec(rng, -1, 1), RandomVec(rng, -1, 1), RandomVec(rng, -1, 1)};
    const Tri Q = {c + RandomVec(rng, -1, 1), c + RandomVec(rng, -1, 1), c + RandomVec(rng, -1, 1)};
    const double gap = SeparatingGap(P, Q);
    if (std::abs(gap) < 1e-9) continue;  // too close to call for the reference
    const bool expected = gap < 0;
    (expected ? hits : misses)++;
    ASSERT_EQ(Intersect(P, Q), expected) << "pair " << i << " gap " << gap;
    ASSERT_EQ(Intersect(Q, P), expected) << "pair " << i;
  }
  EXPECT_GT(hits, count / 10);
  EXPECT_GT(misses, count / 10);
}

// ---------------------------------------------------------------------------
// Closest points.

// Variational-inequality certificate: x is the point of the closed triangle
// T closest to p iff x lies in T and (p - x) . (v - x) <= 0 for T's vertices.
void ExpectClosestOnTriangle(const Vec3& p, const Tri& T, const Vec3& x, const Vec3& bary,
                             double scale) {
  const double tol = 1e-12 * scale;
  EXPECT_GE(bary.minCoeff(), 0.0);
  EXPECT_NEAR(bary.sum(), 1.0, 1e-12);
  EXPECT_LE((bary[0] * T[0] + bary[1] * T[1] + bary[2] * T[2] - x).norm(), 4 * tol);
  const double reach = (p - x).norm() + (T[1] - T[0]).norm() + (T[2] - T[0]).norm();
  for (const Vec3& v : T) EXPECT_LE((p - x).dot(v - x), tol * reach);
}

TEST(PrimitivesClosestPointOnTriangle, VoronoiRegionsKnownAnswers) {
  // Triangle (0,0,0), (2,0,0), (0,2,0); queries at height 0.5 above every
  // region, with their closest points.
  const Tri T0 = {Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(0, 2, 0)};
  struct Case {
    Vec3 p, x;
  };
  const Case cases[] = {
      {Vec3(0.5, 0.5, 0.5), Vec3(0.5, 0.5, 0)},   // face
      {Vec3(0.5, 0.5, -0.5), Vec3(0.5, 0.5, 0)},  // face, below
      {Vec3(0.3, 0.6, 0), Vec3(0.3, 0.6, 0)},     // in the triangle
      {Vec3(1, -1, 0.5), Vec3(1, 0, 0)},          // edge ab
      {Vec3(2, 2, 0.5), Vec3(1, 1, 0)},           // edge bc
      {Vec3(-1, 1, 0.5), Vec3(0, 1, 0)},          // edge ca
      {Vec3(-1, -1, 0.5), Vec3(0, 0, 0)},         // vertex a
      {Vec3(3, -0.5, 0.5), Vec3(2, 0, 0)},        // vertex b
      {Vec3(-0.5, 3, 0.5), Vec3(0, 2, 0)},        // vertex c
      {Vec3(1, 0, 0), Vec3(1, 0, 0)},             // on an edge
  };
  for (const Frame& f : Frames()) {
    const Tri T = {f(T0[0]), f(T0[1]), f(T0[2])};
    for (const Case& c : cases) {
      Vec3 bary;
      const Vec3 x = ClosestPointOnTriangle(f(c.p), T[0], T[1], T[2], &bary);
      EXPECT_LE((x - f(c.x)).norm(), 1e-12 * f.Magnitude())
          << "s=" << f.s << " p=" << c.p.transpose();
      ExpectClosestOnTriangle(f(c.p), T, x, bary, f.Magnitude());
      EXPECT_LE((ClosestPointOnTriangle(f(c.p), T[1], T[2], T[0], nullptr) - x).norm(),
                1e-12 * f.Magnitude());
    }
  }
}

TEST(PrimitivesClosestPointOnTriangle, RandomSatisfiesOptimality) {
  std::mt19937_64 rng(testing::TestSeed() + 20);
  const int count = testing::TestCount(3000);
  for (int i = 0; i < count; ++i) {
    const Tri T = {RandomVec(rng, -1, 1), RandomVec(rng, -1, 1), RandomVec(rng, -1, 1)};
    const Vec3 p = RandomVec(rng, -2, 2);
    Vec3 bary;
    const Vec3 x = ClosestPointOnTriangle(p, T[0], T[1], T[2], &bary);
    // Slivers have ill-conditioned weights (documented); the certificate
    // below holds for the point regardless, so only check weights elsewhere.
    const double ratio = (T[1] - T[0]).cross(T[2] - T[0]).norm() /
                         std::max({(T[1] - T[0]).squaredNorm(), (T[2] - T[1]).squaredNorm(),
                                   (T[0] - T[2]).squaredNorm()});
    if (ratio < 1e-3) continue;
    ExpectClosestOnTriangle(p, T, x, bary, 2.0);
    if (::testing::Test::HasFailure()) FAIL() << "case " << i;
  }
}

TEST(PrimitivesClosestPointOnTriangle, DegenerateAndSliverTriangles) {
  for (const Frame& f : Frames()) {
    const double tol = 1e-12 * f.Magnitude();
    // Collinear: a, c, b on the x axis; the closest point is on segment ab.
    Vec3 bary;
    Vec3 x = ClosestPointOnTriangle(f(Vec3(1, 1, 0)), f(Vec3(0, 0, 0)), f(Vec3(3, 0, 0)),
                                    f(Vec3(2, 0, 0)), &bary);
    EXPECT_LE((x - f(Vec3(1, 0, 0))).norm(), tol);
    EXPECT_TRUE(std::isfinite(bary.sum()));
    EXPECT_NEAR(bary.sum(), 1.0, 1e-12);
    x = ClosestPointOnTriangle(f(Vec3(5, 1, 0)), f(Vec3(0, 0, 0)), f(Vec3(3, 0, 0)),
                               f(Vec3(2, 0, 0)), &bary);
    EXPECT_LE((x - f(Vec3(3, 0, 0))).norm(), tol);
    // All vertices equal.
    x = ClosestPointOnTriangle(f(Vec3(1, 1, 1)), f(Vec3(0, 0, 0)), f(Vec3(0, 0, 0)),
                               f(Vec3(0, 0, 0)), &bary);
    EXPECT_EQ(x, f(Vec3(0, 0, 0)));
    EXPECT_EQ(bary.sum(), 1.0);
    // A sliver of height 1e-9. Rotating it rounds its vertices by ~1e-16,
    // which tilts its plane by ~1e-7 rad, so the exact closest point of the
    // rounded triangle can move by up to its width: the distance and the
    // optimality certificate are checked everywhere, the point itself only
    // where the frame is exact.
    const Vec3 a(0, 0, 0), b(1, 0, 0), c(0.5, 1e-9, 0);
    const Tri S = {f(a), f(b), f(c)};
    const bool exact_frame = f.R.isIdentity() && f.o.isZero();
    auto check = [&](const Vec3& p, const Vec3& expected) {
      const Vec3 x = ClosestPointOnTriangle(f(p), S[0], S[1], S[2], &bary);
      EXPECT_TRUE(std::isfinite(bary.sum()));
      EXPECT_NEAR((x - f(p)).norm(), f.s * (p - expected).norm(), tol) << "s=" << f.s;
      const Vec3 px = f(p) - x;
      for (const Vec3& v : S) EXPECT_LE(px.dot(v - x), tol * 4 * f.Magnitude());
      if (exact_frame) {
        EXPECT_LE((x - f(expected)).norm(), tol) << "s=" << f.s;
      }
    };
    check(Vec3(0.5, 0.5e-9, 0.25), Vec3(0.5, 0.5e-9, 0));  // above the interior
    check(Vec3(0.3, 0.2e-9, 0), Vec3(0.3, 0.2e-9, 0));     // in it: distance ~0
    // Beside it in its plane: the foot on edge ac.
    const Vec3 q(0.25, 0.5, 0);
    check(q, (q.dot(c) / c.squaredNorm()) * c);
  }
}

// Reference: distance of two segments by nested ternary search (the
// distance is convex in s, and the inner minimum over t is closed-form).
double PointSegmentDist(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double l = ab.squaredNorm();
  const double t = l > 0 ? std::clamp((p - a).dot(ab) / l, 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
}

double ReferenceSegmentDist(const Vec3& a0, const Vec3& a1, const Vec3& b0, const Vec3& b1) {
  double lo = 0, hi = 1;
  auto f = [&](double s) { return PointSegmentDist(a0 + s * (a1 - a0), b0, b1); };
  for (int it = 0; it < 200; ++it) {
    const double m1 = lo + (hi - lo) / 3, m2 = hi - (hi - lo) / 3;
    if (f(m1) < f(m2)) {
      hi = m2;
    } else {
      lo = m1;
    }
  }
  return std::min({f(0.5 * (lo + hi)), f(0), f(1)});
}

void ExpectConsistentSegmentResult(const SegmentClosest& r, const Vec3& a0, const Vec3& a1,
                                   const Vec3& b0, const Vec3& b1, double tol) {
  EXPECT_GE(r.s, 0.0);
  EXPECT_LE(r.s, 1.0);
  EXPECT_GE(r.t, 0.0);
  EXPECT_LE(r.t, 1.0);
  EXPECT_LE((a0 + r.s * (a1 - a0) - r.p).norm(), tol);
  EXPECT_LE((b0 + r.t * (b1 - b0) - r.q).norm(), tol);
  EXPECT_EQ(r.dist_sq, (r.p - r.q).squaredNorm());
}

TEST(PrimitivesClosestSegmentSegment, KnownAnswers) {
  for (const Frame& f : Frames()) {
    const double tol = 1e-12 * f.Magnitude();
    auto run = [&](Vec3 a0, Vec3 a1, Vec3 b0, Vec3 b1, double dist, const char* what) {
      const SegmentClosest r = ClosestSegmentSegment(f(a0), f(a1), f(b0), f(b1));
      EXPECT_NEAR(std::sqrt(r.dist_sq), f.s * dist, 2 * tol) << what << " s=" << f.s;
      ExpectConsistentSegmentResult(r, f(a0), f(a1), f(b0), f(b1), tol);
      const SegmentClosest r2 = ClosestSegmentSegment(f(b1), f(b0), f(a0), f(a1));
      EXPECT_NEAR(std::sqrt(r2.dist_sq), f.s * dist, 2 * tol) << what << " swapped";
      return r;
    };
    // Skew, perpendicular, closest in both interiors.
    SegmentClosest r =
        run(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(0.5, -1, 0.5), Vec3(0.5, 1, 0.5), 0.5, "skew");
    EXPECT_NEAR(r.s, 0.75, 1e-12 * f.Magnitude() / f.s);
    EXPECT_NEAR(r.t, 0.5, 1e-12 * f.Magnitude() / f.s);
    // Skew, closest at an endpoint of b.
    run(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(0.5, 0.5, 0.5), Vec3(0.5, 2, 0.5), std::sqrt(0.5),
        "endpoint");
    // Crossing.
    run(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(0, -1, 0), Vec3(0, 1, 0), 0, "crossing");
    // Parallel, overlapping and not.
    run(Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(1, 0.5, 0), Vec3(3, 0.5, 0), 0.5, "parallel");
    run(Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(3, 0.5, 0), Vec3(5, 0.5, 0), std::sqrt(1.25),
        "parallel apart");
    // Collinear, overlapping and not.
    run(Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(1, 0, 0), Vec3(3, 0, 0), 0, "collinear");
    run(Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(4, 0, 0), Vec3(3, 0, 0), 1, "collinear apart");
    // Zero length.
    run(Vec3(1, 1, 0), Vec3(1, 1, 0), Vec3(0, 0, 0), Vec3(2, 0, 0), 1, "point-segment");
    run(Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(3, 1, 0), Vec3(3, 1, 0), std::sqrt(2), "segment-point");
    run(Vec3(1, 1, 0), Vec3(1, 1, 0), Vec3(1, 1, 2), Vec3(1, 1, 2), 2, "point-point");
    // Nearly parallel (1e-9 rad), crossing over each other's middles at
    // height 0.25: the usual normal-equation solution loses this.
    r = run(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(-1, -1e-9, 0.25), Vec3(1, 1e-9, 0.25), 0.25,
            "nearly parallel");
    // Nearly parallel and crossing, offset along their length: solving s and
    // t independently leaves the witnesses ~1e-16 / angle apart.
    for (double angle : {1e-5, 1e-9, 1e-12}) {
      run(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(-0.3, -1.3 * angle, 0), Vec3(1.7, 0.7 * angle, 0), 0,
          "nearly parallel crossing");
    }
  }
}

TEST(PrimitivesClosestSegmentSegment, RandomMatchesReference) {
  std::mt19937_64 rng(testing::TestSeed() + 21);
  const int count = testing::TestCount(3000);
  for (int i = 0; i < count; ++i) {
    const Vec3 a0 = RandomVec(rng, -1, 1), a1 = RandomVec(rng, -1, 1);
    Vec3 b0 = RandomVec(rng, -1, 1), b1 = RandomVec(rng, -1, 1);
    if (i % 4 == 1) b1 = b0 + Uniform(rng, -2, 2) * (a1 - a0);           // parallel
    if (i % 4 == 2) b1 = b0 + (a1 - a0) + 1e-7 * RandomVec(rng, -1, 1);  // nearly parallel
    const SegmentClosest r = ClosestSegmentSegment(a0, a1, b0, b1);
    const double ref = ReferenceSegmentDist(a0, a1, b0, b1);
    const double ref2 = ReferenceSegmentDist(b0, b1, a0, a1);
    ExpectConsistentSegmentResult(r, a0, a1, b0, b1, 1e-14);
    // Never worse than the reference; the reference (a search) is accurate
    // to ~1e-8 on these well-scaled inputs.
    ASSERT_LE(std::sqrt(r.dist_sq), std::min(ref, ref2) + 1e-12) << i;
    ASSERT_GE(std::sqrt(r.dist_sq), std::min(ref, ref2) - 1e-8) << i;
  }
}

// Distance from x to triangle T, through the separately tested routine.
double DistToTriangle(const Vec3& x, const Tri& T) {
  return (ClosestPointOnTriangle(x, T[0], T[1], T[2], nullptr) - x).norm();
}

TriangleClosest ClosestTT(const Tri& P, const Tri& Q) {
  return ClosestTriangleTriangle(P[0], P[1], P[2], Q[0], Q[1], Q[2]);
}

// Optimality certificate for a pair of convex sets: p minimises |p - q| over
// P for the given q and vice versa (first-order conditions of the jointly
// convex objective, sufficient for the global minimum).
void ExpectOptimalPair(const Tri& P, const Tri& Q, const TriangleClosest& r, double scale) {
  const double tol = 1e-11 * scale;
  EXPECT_LE(DistToTriangle(r.p, P), tol);
  EXPECT_LE(DistToTriangle(r.q, Q), tol);
  EXPECT_NEAR(r.dist_sq, (r.p - r.q).squaredNorm(), tol * tol);
  const Vec3 pq = r.q - r.p;
  for (const Vec3& v : P) EXPECT_LE(pq.dot(v - r.p), tol * scale);
  for (const Vec3& w : Q) EXPECT_GE(pq.dot(w - r.q), -tol * scale);
}

TEST(PrimitivesClosestTriangleTriangle, KnownAnswers) {
  const Tri P0 = {Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(0, 2, 0)};
  struct Case {
    const char* what;
    Tri q;
    double dist;
  };
  const Case cases[] = {
      {"parallel above", {Vec3(0.2, 0.2, 0.5), Vec3(1, 0.2, 0.5), Vec3(0.2, 1, 0.5)}, 0.5},
      {"vertex above face", {Vec3(0.5, 0.5, 0.3), Vec3(1, 1, 2), Vec3(0, 1, 2)}, 0.3},
      {"edge-edge skew", {Vec3(1, -1, 0.4), Vec3(1, -1, 3), Vec3(1, -3, 0.4)}, std::sqrt(1.16)},
      {"edge-edge crossing above", {Vec3(1, -1, 0.4), Vec3(1, 1, 0.4), Vec3(1, 0, 3)}, 0.4},
      {"vertex-vertex", {Vec3(-1, -1, 0), Vec3(-1, -2, 0), Vec3(-2, -1, 0)}, std::sqrt(2)},
      {"coplanar apart", {Vec3(2, 2, 0), Vec3(3, 2, 0), Vec3(2, 3, 0)}, std::sqrt(2)},
      {"piercing", {Vec3(0.5, 0.5, -1), Vec3(0.5, 0.5, 1), Vec3(3, 3, 0.5)}, 0},
      {"touching at a vertex", {Vec3(0.5, 0.5, 0), Vec3(1, 1, 2), Vec3(0, 1, 2)}, 0},
      {"degenerate segment above",
       {Vec3(0.5, 0.5, 0.7), Vec3(1, 0.5, 0.7), Vec3(2, 0.5, 0.7)},
       0.7},
      {"degenerate point above",
       {Vec3(0.5, 0.5, 0.7), Vec3(0.5, 0.5, 0.7), Vec3(0.5, 0.5, 0.7)},
       0.7},
  };
  for (const Frame& f : Frames()) {
    const Tri P = {f(P0[0]), f(P0[1]), f(P0[2])};
    for (const Case& c : cases) {
      const Tri Q = {f(c.q[0]), f(c.q[1]), f(c.q[2])};
      const TriangleClosest r = ClosestTT(P, Q);
      EXPECT_NEAR(std::sqrt(r.dist_sq), f.s * c.dist, 1e-12 * f.Magnitude())
          << c.what << " s=" << f.s << " rotated " << !f.R.isIdentity();
      if (c.dist > 0) ExpectOptimalPair(P, Q, r, f.Magnitude());
      if (c.dist == 0 && f.R.isIdentity() && f.o.isZero()) {
        EXPECT_EQ(r.dist_sq, 0.0) << c.what;
        EXPECT_EQ(r.p, r.q) << c.what;
      }
      if (c.dist == 0) {
        EXPECT_LE(DistToTriangle(r.p, P), 1e-11 * f.Magnitude()) << c.what;
        EXPECT_LE(DistToTriangle(r.p, Q), 1e-11 * f.Magnitude()) << c.what;
      }
      const TriangleClosest rs = ClosestTT(Q, P);  // swapping swaps the witnesses
      EXPECT_NEAR(std::sqrt(rs.dist_sq), std::sqrt(r.dist_sq), 1e-12 * f.Magnitude());
    }
  }
}

// Dense sampling of both triangles: the reported distance is never above a
// sampled one, and the densest sample pair is within the grid resolution.
TEST(PrimitivesClosestTriangleTriangle, RandomMatchesDenseSampling) {
  std::mt19937_64 rng(testing::TestSeed() + 30);
  const int count = std::max(1, testing::TestCount(3000) / 30);
  constexpr int kN = 40;  // subdivisions per edge
  auto samples = [](const Tri& T) {
    std::vector<Vec3> s;
    for (int i = 0; i <= kN; ++i) {
      for (int j = 0; i + j <= kN; ++j) {
        s.push_back(T[0] + (double(i) / kN) * (T[1] - T[0]) + (double(j) / kN) * (T[2] - T[0]));
      }
    }
    return s;
  };
  int intersecting = 0;
  for (int i = 0; i < count; ++i) {
    const Vec3 c = RandomVec(rng, -1.5, 1.5);
    const Tri P = {RandomVec(rng, -1, 1), RandomVec(rng, -1, 1), RandomVec(rng, -1, 1)};
    const Tri Q = {c + RandomVec(rng, -1, 1), c + RandomVec(rng, -1, 1), c + RandomVec(rng, -1, 1)};
    const TriangleClosest r = ClosestTT(P, Q);
    const double reported = std::sqrt(r.dist_sq);
    const std::vector<Vec3> sp = samples(P), sq = samples(Q);
    double sampled_sq = kInf;
    for (const Vec3& x : sp) {
      for (const Vec3& y : sq) sampled_sq = std::min(sampled_sq, (x - y).squaredNorm());
    }
    auto longest = [](const Tri& T) {
      return std::max({(T[1] - T[0]).norm(), (T[2] - T[1]).norm(), (T[0] - T[2]).norm()});
    };
    const double resolution = (longest(P) + longest(Q)) / kN;
    ASSERT_LE(reported, std::sqrt(sampled_sq) + 1e-12) << i;
    ASSERT_GE(reported, std::sqrt(sampled_sq) - resolution) << i;
    ASSERT_EQ(r.dist_sq == 0, Intersect(P, Q)) << i;
    if (r.dist_sq == 0) {
      ++intersecting;
      EXPECT_EQ(r.p, r.q);
      EXPECT_LE(DistToTriangle(r.p, P), 1e-12) << i;
      EXPECT_LE(DistToTriangle(r.p, Q), 1e-12) << i;
    } else {
      ExpectOptimalPair(P, Q, r, 2.0);
    }
  }
  EXPECT_GT(intersecting, 0);
  EXPECT_LT(intersecting, count);
}

TEST(PrimitivesClosestTriangleTriangle, RandomOptimalityCertificate) {
  std::mt19937_64 rng(testing::TestSeed() + 31);
  const int count = testing::TestCount(3000);
  for (int i = 0; i < count; ++i) {
    const Vec3 c = RandomVec(rng, -2, 2);
    Tri P = {RandomVec(rng, -1, 1), RandomVec(rng, -1, 1), RandomVec(rng, -1, 1)};
    const Tri Q = {c + RandomVec(rng, -1, 1), c + RandomVec(rng, -1, 1), c + RandomVec(rng, -1, 1)};
    if (i % 5 == 0) P[2] = P[0] + 0.3 * (P[1] - P[0]);  // degenerate
    const TriangleClosest r = ClosestTT(P, Q);
    if (r.dist_sq == 0) {
      ASSERT_TRUE(Intersect(P, Q)) << i;
      continue;
    }
    ASSERT_FALSE(Intersect(P, Q)) << i;
    ExpectOptimalPair(P, Q, r, 3.0);
    if (::testing::Test::HasFailure()) FAIL() << "case " << i;
  }
}

// ---------------------------------------------------------------------------
// Time of impact.

// Result of one time-of-impact call (bundled so that the call happens
// before its output is read).
struct Toi {
  bool hit;
  double t;
};

// t at a known answer, with the tolerance of the contract: position error a
// few kContactTol * S, converted into time.
// Calls f(args..., &t).
template <typename F, typename... Args>
Toi Call(F&& f, const Args&... args) {
  Toi r{false, -1};
  r.hit = f(args..., &r.t);
  return r;
}

void ExpectToi(const Toi& r, double expected, double speed, double magnitude, const char* what) {
  ASSERT_TRUE(r.hit) << what;
  EXPECT_NEAR(r.t, expected, 4e-12 * magnitude / speed) << what;
}

TEST(PrimitivesPointTriangleToi, KnownAnswers) {
  const Vec3 a0(0, 0, 0), b0(2, 0, 0), c0(0, 2, 0);
  for (const Frame& f : Frames()) {
    const Vec3 a = f(a0), b = f(b0), c = f(c0);
    const double mag = f.Magnitude();
    auto toi = [&](const Vec3& p, const Vec3& d, double t_max, double* t) {
      return PointTriangleToi(f(p), f.Dir(d), a, b, c, t_max, t);
    };
    double t = -1;
    // Falling onto the face, straight and oblique, from either side.
    ExpectToi(Call(toi, Vec3(0.5, 0.5, 1), Vec3(0, 0, -2), 1), 0.5, 2 * f.s, mag, "drop");
    ExpectToi(Call(toi, Vec3(0.5, 0.5, -1), Vec3(0.2, 0.1, 4), 1), 0.25, 4 * f.s, mag, "rise");
    // Through an edge and a vertex.
    ExpectToi(Call(toi, Vec3(1, 0, 1), Vec3(0, 0, -1), 2), 1, f.s, mag, "onto edge");
    ExpectToi(Call(toi, Vec3(2, 0, 1), Vec3(0, 0, -1), 2), 1, f.s, mag, "onto vertex");
    // In the plane: 2-D entry through an edge, and through a vertex.
    ExpectToi(Call(toi, Vec3(0.5, -1, 0), Vec3(0, 2, 0), 1), 0.5, 2 * f.s, mag, "2-D edge");
    ExpectToi(Call(toi, Vec3(3, -1, 0), Vec3(-1, 1, 0), 2), 1, std::sqrt(2) * f.s, mag,
              "2-D vertex");
    ExpectToi(Call(toi, Vec3(4, 0, 0), Vec3(-1, 0, 0), 3), 2, f.s, mag, "2-D along edge");
    // Already on the triangle: t = 0 whatever the motion.
    ASSERT_TRUE(toi(Vec3(0.5, 0.5, 0), Vec3(0, 0, 1), 1, &t));
    EXPECT_EQ(t, 0);
    ASSERT_TRUE(toi(Vec3(0.5, 0.5, 0), Vec3(1, 0, 0), 1, &t));
    EXPECT_EQ(t, 0);
    ASSERT_TRUE(toi(Vec3(0, 1, 0), Vec3(-1, 0, 0), 1, &t));
    EXPECT_EQ(t, 0);
    // Misses: too short, moving away, parallel above, passing beside.
    EXPECT_FALSE(toi(Vec3(0.5, 0.5, 1), Vec3(0, 0, -1), 0.99, &t));
    EXPECT_FALSE(toi(Vec3(0.5, 0.5, 1), Vec3(0, 0, 1), 10, &t));
    EXPECT_FALSE(toi(Vec3(-1, 0.5, 1e-3), Vec3(5, 0, 0), 1, &t));
    EXPECT_FALSE(toi(Vec3(1.01, 1.01, 1), Vec3(0, 0, -1), 2, &t));
    EXPECT_FALSE(toi(Vec3(0.5, -1, 0), Vec3(0, -1, 0), 5, &t));
    // Unbounded and invalid t_max.
    ExpectToi(Call(toi, Vec3(0.5, 0.5, 100), Vec3(0, 0, -1), kInf), 100, f.s, mag, "t_max=inf");
    t = -1;
    EXPECT_FALSE(toi(Vec3(0.5, 0.5, 1), Vec3(0, 0, -1), std::nan(""), &t));
    EXPECT_FALSE(toi(Vec3(0.5, 0.5, 1), Vec3(0, 0, -1), -1, &t));
    EXPECT_EQ(t, -1);  // untouched on a miss
    // Zero displacement: contact only if already touching.
    EXPECT_FALSE(toi(Vec3(0.5, 0.5, 1), Vec3(0, 0, 0), 1, &t));
    ASSERT_TRUE(toi(Vec3(0.5, 0.5, 0), Vec3(0, 0, 0), 1, &t));
    EXPECT_EQ(t, 0);
  }
}

TEST(PrimitivesPointTriangleToi, DegenerateTriangles) {
  for (const Frame& f : Frames()) {
    const double mag = f.Magnitude();
    double t;
    // Collinear triangle = segment from (0,0,0) to (2,0,0).
    const Vec3 a = f(Vec3(0, 0, 0)), b = f(Vec3(2, 0, 0)), c = f(Vec3(1, 0, 0));
    ExpectToi(Call(PointTriangleToi, f(Vec3(1.5, 0, 2)), f.Dir(Vec3(0, 0, -1)), a, b, c, 5), 2, f.s,
              mag, "onto segment");
    ExpectToi(Call(PointTriangleToi, f(Vec3(4, 0, 0)), f.Dir(Vec3(-1, 0, 0)), a, b, c, 5), 2, f.s,
              mag, "along segment");
    EXPECT_FALSE(PointTriangleToi(f(Vec3(1.5, 0.1, 2)), f.Dir(Vec3(0, 0, -1)), a, b, c, 5, &t));
    // Point triangle.
    const Vec3 q = f(Vec3(1, 1, 1));
    ExpectToi(Call(PointTriangleToi, f(Vec3(1, 1, 4)), f.Dir(Vec3(0, 0, -1)), q, q, q, 5), 3, f.s,
              mag, "onto point");
    EXPECT_FALSE(PointTriangleToi(f(Vec3(1, 1.5, 4)), f.Dir(Vec3(0, 0, -1)), q, q, q, 5, &t));
    // A 1e-9 sliver: hit through its interior, and in its plane from the
    // side, far away.
    const Vec3 sa = f(Vec3(0, 0, 0)), sb = f(Vec3(1, 0, 0)), sc = f(Vec3(0.5, 1e-9, 0));
    ExpectToi(
        Call(PointTriangleToi, f(Vec3(0.5, 0.25e-9, 1)), f.Dir(Vec3(0, 0, -1)), sa, sb, sc, 2), 1,
        f.s, mag, "sliver interior");
    ExpectToi(Call(PointTriangleToi, f(Vec3(0.5, -3, 0)), f.Dir(Vec3(0, 1, 0)), sa, sb, sc, 5), 3,
              f.s, mag, "sliver in plane");
  }
}

// Distance from the point p + t d to T (for t >= 0).
double PointDistAt(const Vec3& p, const Vec3& d, double t, const Tri& T) {
  return DistToTriangle(p + t * d, T);
}

TEST(PrimitivesPointTriangleToi, RandomContactAndSeparation) {
  std::mt19937_64 rng(testing::TestSeed() + 40);
  const int count = testing::TestCount(3000);
  int hits = 0, misses = 0;
  for (int i = 0; i < count; ++i) {
    const Tri T = {RandomVec(rng, -1, 1), RandomVec(rng, -1, 1), RandomVec(rng, -1, 1)};
    // Aim at a point near the triangle so that about half the cases hit.
    const Vec3 target =
        T[0] + Uniform(rng, -0.3, 1) * (T[1] - T[0]) + Uniform(rng, -0.3, 1) * (T[2] - T[0]);
    const Vec3 d = RandomVec(rng, -1, 1);
    const double t0 = Uniform(rng, 0.05, 1.5);
    Vec3 p = target - t0 * d;
    if (i % 5 == 0) {  // in-plane motion
      const Vec3 n = (T[1] - T[0]).cross(T[2] - T[0]).normalized();
      const Vec3 din = d - d.dot(n) * n;
      p = target - t0 * din;
      double t;
      const bool hit = PointTriangleToi(p, din, T[0], T[1], T[2], 1, &t);
      if (hit) {
        ASSERT_LE(PointDistAt(p, din, t, T), 1e-11) << i;
        if (t > 1e-6) {
          ASSERT_GT(PointDistAt(p, din, t - 1e-6, T), 0) << i;
        }
      }
      continue;
    }
    double t = -1;
    const bool hit = PointTriangleToi(p, d, T[0], T[1], T[2], 1, &t);
    // Exact reference: does the closed segment [p, p + d] meet T?
    const Vec3 e = p + d;
    const bool exact = TrianglesIntersect(p, e, e, T[0], T[1], T[2]);
    if (exact) {
      ASSERT_TRUE(hit) << "missed contact " << i;
    }
    if (!hit) {
      ++misses;
      continue;
    }
    ++hits;
    ASSERT_GE(t, 0);
    ASSERT_LE(t, 1);
    // Touching at t, separated just before, and never touching earlier.
    ASSERT_LE(PointDistAt(p, d, t, T), 1e-11) << i;
    if (!exact) {
      // A tolerance contact: the path passes within ~kContactTol of T.
      ASSERT_LE(ClosestTriangleTriangle(p, e, e, T[0], T[1], T[2]).dist_sq, 1e-20) << i;
    }
    if (t > 1e-7) {
      ASSERT_GT(PointDistAt(p, d, t * (1 - 1e-7), T), 0) << i;
      for (int k = 0; k < 20; ++k) {
        ASSERT_GT(PointDistAt(p, d, t * k / 20.0 * (1 - 1e-7), T), 0) << i;
      }
    }
  }
  EXPECT_GT(hits, count / 10);
  EXPECT_GT(misses, count / 10);
}

TEST(PrimitivesSegmentSegmentToi, KnownAnswers) {
  for (const Frame& f : Frames()) {
    const double mag = f.Magnitude();
    auto toi = [&](Vec3 a0, Vec3 a1, Vec3 d, Vec3 b0, Vec3 b1, double t_max, double* t) {
      return SegmentSegmentToi(f(a0), f(a1), f.Dir(d), f(b0), f(b1), t_max, t);
    };
    double t = -1;
    // Skew perpendicular segments, moving along the common normal.
    ExpectToi(Call(toi, Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(0, 0, -2), Vec3(0.5, -1, 0),
                   Vec3(0.5, 1, 0), 1),
              0.5, 2 * f.s, mag, "skew");
    // Obliquely, hitting b's endpoint.
    ExpectToi(Call(toi, Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(0, -1, -1), Vec3(0.5, -1, 0),
                   Vec3(0.5, -3, 0), 2),
              1, std::sqrt(2) * f.s, mag, "endpoint of b");
    // Coplanar motion: a moves in the plane of both until its endpoint
    // reaches b.
    ExpectToi(
        Call(toi, Vec3(-3, 0, 0), Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(0, -1, 0), Vec3(0, 1, 0), 2),
        1, f.s, mag, "coplanar endpoint");
    // Coplanar, b's endpoint hits a's interior (the -d endpoint event).
    ExpectToi(Call(toi, Vec3(-1, 2, 0), Vec3(1, 2, 0), Vec3(0, -1, 0), Vec3(0, -1, 0),
                   Vec3(0, 0.5, 0), 3),
              1.5, f.s, mag, "coplanar b endpoint");
    // Parallel, side by side in a plane.
    ExpectToi(
        Call(toi, Vec3(0, 1, 0), Vec3(2, 1, 0), Vec3(0, -1, 0), Vec3(1, 0, 0), Vec3(3, 0, 0), 2), 1,
        f.s, mag, "parallel");
    // Parallel in parallel planes, moving across.
    ExpectToi(
        Call(toi, Vec3(0, 1, 1), Vec3(2, 1, 1), Vec3(0, -1, -1), Vec3(1, 0, 0), Vec3(3, 0, 0), 2),
        1, std::sqrt(2) * f.s, mag, "parallel planes");
    // Collinear, end to end.
    ExpectToi(
        Call(toi, Vec3(-3, 0, 0), Vec3(-1, 0, 0), Vec3(0.5, 0, 0), Vec3(0, 0, 0), Vec3(2, 0, 0), 4),
        2, 0.5 * f.s, mag, "collinear");
    // Zero-length moving segment, zero-length fixed one, both.
    ExpectToi(
        Call(toi, Vec3(1, 1, 1), Vec3(1, 1, 1), Vec3(0, -1, -1), Vec3(0, 0, 0), Vec3(2, 0, 0), 2),
        1, std::sqrt(2) * f.s, mag, "point vs segment");
    ExpectToi(
        Call(toi, Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(0, 0, 1), Vec3(1, 0, 3), Vec3(1, 0, 3), 5), 3,
        f.s, mag, "segment vs point");
    ExpectToi(
        Call(toi, Vec3(1, 1, 1), Vec3(1, 1, 1), Vec3(1, 1, 1), Vec3(2, 2, 2), Vec3(2, 2, 2), 5), 1,
        std::sqrt(3) * f.s, mag, "point vs point");
    // Already touching: 0.
    ASSERT_TRUE(
        toi(Vec3(-1, 0, 0), Vec3(1, 0, 0), Vec3(0, 0, 1), Vec3(0, -1, 0), Vec3(0, 1, 0), 1, &t));
    EXPECT_EQ(t, 0);
    ASSERT_TRUE(
        toi(Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(1, 0, 0), Vec3(2, 0, 0), Vec3(3, 0, 0), 1, &t));
    EXPECT_EQ(t, 0);
    // Misses: moving away, moving parallel to both, passing by, too short.
    EXPECT_FALSE(
        toi(Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(0, 0, 1), Vec3(0, -1, 0), Vec3(0, 1, 0), 9, &t));
    EXPECT_FALSE(
        toi(Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(1, 1, 0), Vec3(0, -1, 0), Vec3(0, 1, 0), 9, &t));
    EXPECT_FALSE(
        toi(Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(3, 0, -1), Vec3(0, -1, 0), Vec3(0, 1, 0), 9, &t));
    EXPECT_FALSE(toi(Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(0, 0, -1), Vec3(0, -1, 0), Vec3(0, 1, 0),
                     0.999, &t));
    EXPECT_FALSE(
        toi(Vec3(-3, 0, 0), Vec3(-1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 0), Vec3(2, 0, 0), 9, &t));
    t = -1;
    EXPECT_FALSE(toi(Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(0, 0, -1), Vec3(0, -1, 0), Vec3(0, 1, 0),
                     std::nan(""), &t));
    EXPECT_EQ(t, -1);
  }
}

double SegmentDistAt(const Vec3& a0, const Vec3& a1, const Vec3& d, double t, const Vec3& b0,
                     const Vec3& b1) {
  return std::sqrt(ClosestSegmentSegment(a0 + t * d, a1 + t * d, b0, b1).dist_sq);
}

TEST(PrimitivesSegmentSegmentToi, RandomContactAndSeparation) {
  std::mt19937_64 rng(testing::TestSeed() + 50);
  const int count = testing::TestCount(3000);
  int hits = 0, misses = 0;
  for (int i = 0; i < count; ++i) {
    const Vec3 b0 = RandomVec(rng, -1, 1), b1 = RandomVec(rng, -1, 1);
    Vec3 a0 = RandomVec(rng, -1, 1), a1 = RandomVec(rng, -1, 1);
    Vec3 d = RandomVec(rng, -1, 1);
    // Aim a's interior at b's interior so that many cases hit.
    const double s = Uniform(rng, -0.2, 1.2), u = Uniform(rng, -0.2, 1.2);
    const double t0 = Uniform(rng, 0.05, 1.5);
    const Vec3 shift = (b0 + u * (b1 - b0)) - (a0 + s * (a1 - a0)) - t0 * d;
    a0 += shift;
    a1 += shift;
    const int kind = i % 4;
    if (kind == 1) {  // coplanar motion: d in the plane of both segments
      const Vec3 n = (a1 - a0).cross(b1 - b0).normalized();
      d -= d.dot(n) * n;
      const Vec3 off = (b0 - a0).dot(n) * n;
      a0 += off;
      a1 += off;
    } else if (kind == 2) {  // parallel segments
      a1 = a0 + Uniform(rng, 0.2, 2) * (b1 - b0);
    }
    double t = -1;
    const bool hit = SegmentSegmentToi(a0, a1, d, b0, b1, 1, &t);
    if (kind == 0) {
      // Exact reference in general position: the swept parallelogram
      // against segment b.
      const Vec3 e0 = a0 + d, e1 = a1 + d;
      const bool exact =
          TrianglesIntersect(a0, a1, e1, b0, b1, b1) || TrianglesIntersect(a0, e1, e0, b0, b1, b1);
      if (exact) {
        ASSERT_TRUE(hit) << "missed contact " << i;
      }
    }
    if (!hit) {
      ++misses;
      // No contact anywhere along the motion.
      for (int k = 0; k <= 50; ++k) ASSERT_GT(SegmentDistAt(a0, a1, d, k / 50.0, b0, b1), 0) << i;
      continue;
    }
    ++hits;
    ASSERT_GE(t, 0);
    ASSERT_LE(t, 1);
    ASSERT_LE(SegmentDistAt(a0, a1, d, t, b0, b1), 1e-11) << i << " kind " << kind;
    if (t > 1e-7) {
      ASSERT_GT(SegmentDistAt(a0, a1, d, t * (1 - 1e-7), b0, b1), 0) << i << " kind " << kind;
      for (int k = 0; k < 20; ++k) {
        ASSERT_GT(SegmentDistAt(a0, a1, d, t * k / 20.0 * (1 - 1e-7), b0, b1), 0) << i;
      }
    }
  }
  EXPECT_GT(hits, count / 10);
  EXPECT_GT(misses, count / 10);
}

}  // namespace
}  // namespace hapticpd::pd::internal
