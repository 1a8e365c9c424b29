// Geometry-core benchmark: BVH build for the bunny, and per-query latency of
// collision, proximity, distance and translational CCD of the stick against
// the bunny in near-contact poses, beside FCL's collide and distance on the
// same poses. Prints p50/p99/p99.9 per query and our/FCL ratios, and writes
// a CSV (--csv=FILE, default bench_geometry.csv) a person can plot.
//
//   ./build/release/tests/bench/bench_geometry [--models DIR] [--poses N]
//
// Without ../shared/models the bunny is replaced by a procedural torus knot
// of similar size (and the output says so).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <random>

#include "pd/queries.h"
#include "pd/shapes.h"
#include "tests/oracles/fcl_oracle.h"

namespace hp = hapticpd;
namespace pd = hapticpd::pd;

namespace {

struct Setup {
  std::string scene_name;
  pd::ModelPtr scene;
  pd::ModelPtr stick;
  std::unique_ptr<hp::testing::FclModel> fcl_scene, fcl_stick;
  std::vector<hp::Pose> poses;   // near-contact poses of the stick
  std::vector<hp::Vec3> sweeps;  // CCD displacement per pose (towards the surface)
  std::filesystem::path scene_path;
};

Setup* g_setup = nullptr;
std::map<std::string, std::vector<double>> g_samples;  // name -> µs per query

void Record(const std::string& name, double us) { g_samples[name].push_back(us); }

template <typename F>
void TimedLoop(benchmark::State& state, const std::string& name, F&& f) {
  std::size_t i = 0;
  const auto& poses = g_setup->poses;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    f(i % poses.size());
    const auto t1 = std::chrono::steady_clock::now();
    Record(name, std::chrono::duration<double, std::micro>(t1 - t0).count());
    ++i;
  }
}

void BM_BvhBuild(benchmark::State& state) {
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    pd::Bvh bvh(g_setup->scene->mesh());
    benchmark::DoNotOptimize(bvh.nodes().data());
    Record(
        "bvh_build_scene",
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
  }
}

void BM_FclBuild(benchmark::State& state) {
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    hp::testing::FclModel m(g_setup->scene->mesh());
    benchmark::DoNotOptimize(&m);
    Record(
        "fcl_build_scene",
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
  }
}

void BM_Collide(benchmark::State& state) {
  pd::QueryScratch s;
  pd::CollisionResult r;
  pd::CollisionRequest req;
  req.containment = false;  // same question FCL answers
  TimedLoop(state, "collide", [&](std::size_t i) {
    benchmark::DoNotOptimize(pd::Collide(*g_setup->stick, g_setup->poses[i], *g_setup->scene,
                                         hp::Pose::Identity(), req, &r, &s));
  });
}

void BM_CollideContainment(benchmark::State& state) {
  pd::QueryScratch s;
  pd::CollisionResult r;
  pd::CollisionRequest req;
  TimedLoop(state, "collide+containment", [&](std::size_t i) {
    benchmark::DoNotOptimize(pd::Collide(*g_setup->stick, g_setup->poses[i], *g_setup->scene,
                                         hp::Pose::Identity(), req, &r, &s));
  });
}

void BM_FclCollide(benchmark::State& state) {
  TimedLoop(state, "fcl_collide", [&](std::size_t i) {
    benchmark::DoNotOptimize(hp::testing::FclCollide(*g_setup->fcl_stick, g_setup->poses[i],
                                                     *g_setup->fcl_scene, hp::Pose::Identity()));
  });
}

void BM_Distance(benchmark::State& state) {
  pd::QueryScratch s;
  TimedLoop(state, "distance", [&](std::size_t i) {
    benchmark::DoNotOptimize(pd::Distance(*g_setup->stick, g_setup->poses[i], *g_setup->scene,
                                          hp::Pose::Identity(), nullptr, &s));
  });
}

void BM_FclDistance(benchmark::State& state) {
  TimedLoop(state, "fcl_distance", [&](std::size_t i) {
    benchmark::DoNotOptimize(hp::testing::FclDistance(*g_setup->fcl_stick, g_setup->poses[i],
                                                      *g_setup->fcl_scene, hp::Pose::Identity()));
  });
}

void BM_Proximity(benchmark::State& state) {
  pd::QueryScratch s;
  pd::ProximityResult r;
  pd::ProximityRequest req;
  req.tolerance = 1e-3 * g_setup->scene->mesh().size();
  TimedLoop(state, "proximity", [&](std::size_t i) {
    pd::Proximity(*g_setup->stick, g_setup->poses[i], *g_setup->scene, hp::Pose::Identity(), req,
                  &r, &s);
    benchmark::DoNotOptimize(r.pairs.data());
  });
}

void BM_TranslationalCcd(benchmark::State& state) {
  pd::QueryScratch s;
  pd::CcdResult r;
  pd::CcdRequest req;
  req.feature_tolerance = 1e-6 * g_setup->scene->mesh().size();
  TimedLoop(state, "translational_ccd", [&](std::size_t i) {
    hp::Pose X0 = g_setup->poses[i];
    X0.t -= g_setup->sweeps[i];
    benchmark::DoNotOptimize(pd::TranslationalCcd(*g_setup->stick, X0, g_setup->sweeps[i],
                                                  *g_setup->scene, hp::Pose::Identity(), req, &r,
                                                  &s));
  });
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(k, v.size() - 1)];
}

void BuildSetup(const std::string& models_dir, int num_poses) {
  g_setup = new Setup;
  const std::filesystem::path bunny = std::filesystem::path(models_dir) / "stanford-bunny.obj";
  if (!models_dir.empty() && std::filesystem::exists(bunny)) {
    g_setup->scene = pd::MakeModel(pd::LoadMesh(bunny.string()));
    g_setup->scene_name = "stanford-bunny.obj";
  } else {
    std::cout << "NOTE: " << bunny << " not found; using a procedural torus knot instead\n";
    g_setup->scene = pd::MakeModel(pd::shapes::TorusKnot(2, 3, 0.06, 0.015, 1200, 30));
    g_setup->scene_name = "torus knot (stand-in)";
  }
  g_setup->stick = pd::MakeModel(pd::shapes::Stick());
  g_setup->fcl_scene = std::make_unique<hp::testing::FclModel>(g_setup->scene->mesh());
  g_setup->fcl_stick = std::make_unique<hp::testing::FclModel>(g_setup->stick->mesh());

  // Near-contact poses: the stick's tip within ±2 mm of a random surface
  // point, the stick pointing roughly into the surface.
  std::mt19937_64 rng(42);
  std::normal_distribution<double> n(0, 1);
  const auto& mesh = g_setup->scene->mesh();
  std::uniform_int_distribution<std::size_t> pick(0, mesh.num_triangles() - 1);
  const double tip = g_setup->stick->mesh().bounds().hi.z();
  while (static_cast<int>(g_setup->poses.size()) < num_poses) {
    const std::size_t f = pick(rng);
    const auto& t = mesh.triangles()[f];
    const hp::Vec3 c =
        (mesh.vertices()[t[0]] + mesh.vertices()[t[1]] + mesh.vertices()[t[2]]) / 3.0;
    const hp::Vec3 normal = mesh.face_normals()[f];
    if (normal.squaredNorm() == 0) continue;
    // Stick axis (its +z) points against the normal, tilted randomly.
    const hp::Vec3 axis = (-normal + 0.4 * hp::Vec3(n(rng), n(rng), n(rng))).normalized();
    const hp::Mat3 R = hp::Quat::FromTwoVectors(hp::Vec3::UnitZ(), axis).toRotationMatrix();
    const double depth = 0.002 * n(rng);  // + into the surface
    hp::Pose X{R, c + axis * depth - R * hp::Vec3(0, 0, tip)};
    g_setup->poses.push_back(X);
    g_setup->sweeps.push_back(axis * 0.01);  // CCD: approach from 1 cm back
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::string models = HAPTICPD_MODELS_DIR;
  std::string csv = "bench_geometry.csv";
  int num_poses = 1000;
  std::vector<char*> rest = {argv[0]};
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--models") && i + 1 < argc) {
      models = argv[++i];
    } else if (!std::strcmp(argv[i], "--poses") && i + 1 < argc) {
      num_poses = std::max(1, std::atoi(argv[++i]));
    } else if (!std::strncmp(argv[i], "--csv=", 6)) {
      csv = argv[i] + 6;
    } else {
      rest.push_back(argv[i]);
    }
  }
  int rest_argc = static_cast<int>(rest.size());
  BuildSetup(models, num_poses);
  std::cout << "scene: " << g_setup->scene_name << " (" << g_setup->scene->mesh().num_triangles()
            << " triangles), probe: stick (" << g_setup->stick->mesh().num_triangles()
            << " triangles), " << g_setup->poses.size() << " near-contact poses\n";

  benchmark::RegisterBenchmark("bvh_build/scene", BM_BvhBuild)->Unit(benchmark::kMillisecond);
  benchmark::RegisterBenchmark("fcl_build/scene", BM_FclBuild)->Unit(benchmark::kMillisecond);
  const auto iters = static_cast<benchmark::IterationCount>(g_setup->poses.size() * 5);
  benchmark::RegisterBenchmark("collide", BM_Collide)->Iterations(iters);
  benchmark::RegisterBenchmark("collide+containment", BM_CollideContainment)->Iterations(iters);
  benchmark::RegisterBenchmark("fcl_collide", BM_FclCollide)->Iterations(iters);
  benchmark::RegisterBenchmark("distance", BM_Distance)->Iterations(iters);
  benchmark::RegisterBenchmark("fcl_distance", BM_FclDistance)->Iterations(iters);
  benchmark::RegisterBenchmark("proximity", BM_Proximity)->Iterations(iters);
  benchmark::RegisterBenchmark("translational_ccd", BM_TranslationalCcd)->Iterations(iters);
  benchmark::Initialize(&rest_argc, rest.data());
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();

  std::ofstream out(csv);
  out << "query,count,p50_us,p99_us,p999_us,max_us\n";
  std::cout << "\n"
            << std::left << std::setw(22) << "query" << std::right << std::setw(8) << "count"
            << std::setw(12) << "p50 us" << std::setw(12) << "p99 us" << std::setw(12) << "p99.9 us"
            << std::setw(12) << "max us"
            << "\n";
  for (const auto& [name, v] : g_samples) {
    const double p50 = Percentile(v, 0.5), p99 = Percentile(v, 0.99), p999 = Percentile(v, 0.999),
                 mx = Percentile(v, 1.0);
    std::cout << std::left << std::setw(22) << name << std::right << std::setw(8) << v.size()
              << std::fixed << std::setprecision(2) << std::setw(12) << p50 << std::setw(12) << p99
              << std::setw(12) << p999 << std::setw(12) << mx << "\n";
    out << name << "," << v.size() << "," << p50 << "," << p99 << "," << p999 << "," << mx << "\n";
  }
  auto ratio = [](const char* ours, const char* peer) {
    const auto a = g_samples.find(ours), b = g_samples.find(peer);
    if (a == g_samples.end() || b == g_samples.end()) return;
    std::cout << "ratio " << ours << " / " << peer << ": p50 " << std::setprecision(2)
              << Percentile(a->second, 0.5) / Percentile(b->second, 0.5) << ", p99 "
              << Percentile(a->second, 0.99) / Percentile(b->second, 0.99)
              << "  (< 1 means we are faster)\n";
  };
  std::cout << "\n";
  ratio("collide", "fcl_collide");
  ratio("distance", "fcl_distance");
  ratio("bvh_build_scene", "fcl_build_scene");
  std::cout << "CSV written to " << csv << "\n";
  return 0;
}
