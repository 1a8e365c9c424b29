// Faults over loopback TCP that the other suites do not already cover:
// a mesh upload (client-streaming AddBody) abandoned after some chunks, or
// after every byte but before the half-close, adds no body and leaves the
// server healthy; an observer that never reads (not even its snapshot) does
// not stop a device session or another observer.
//
// Covered elsewhere and not repeated here: a server shut down and restarted
// on the same port during a device session (tests/client/session_test.cc,
// ServerLossFadesTheForceAndTheSessionReconnects: the force fades, the
// session reconnects, no stale force after the return); an observer that
// stops reading after its snapshot (tests/server/observer_test.cc); a
// one-chunk upload cancelled (tests/server/lifecycle_test.cc).
#include <gtest/gtest.h>

#include <atomic>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tests/server/server_harness.h"

namespace hapticpd::testing {
namespace {

/// OBJ text of `n` disjoint tetrahedra (4n triangles).
std::string TetrahedraObj(int n) {
  std::ostringstream os;
  for (int i = 0; i < n; ++i) {
    const double x = 0.1 * i;
    os << "v " << x << " 0 0\nv " << x + 0.05 << " 0 0\nv " << x << " 0.05 0\nv " << x
       << " 0 0.05\n";
    const int b = 4 * i + 1;
    os << "f " << b << ' ' << b + 2 << ' ' << b + 1 << "\nf " << b << ' ' << b + 1 << ' ' << b + 3
       << "\nf " << b << ' ' << b + 3 << ' ' << b + 2 << "\nf " << b + 1 << ' ' << b + 2 << ' '
       << b + 3 << '\n';
  }
  return os.str();
}

std::vector<v1::AddBodyRequest> Upload(const std::string& id, const std::string& obj,
                                       std::size_t chunk_bytes) {
  std::vector<v1::AddBodyRequest> out(1);
  auto* h = out[0].mutable_header();
  h->set_scene_id("default");
  h->set_format(v1::MESH_FORMAT_OBJ);
  h->mutable_spec()->set_body_id(id);
  h->set_total_bytes(obj.size());
  for (std::size_t at = 0; at < obj.size(); at += chunk_bytes) {
    out.emplace_back().set_chunk(obj.substr(at, chunk_bytes));
  }
  return out;
}

TEST(Faults, UploadAbandonedMidStreamAddsNoBody) {
  ServerHarness h(Transport::kTcp);
  auto scenes = h.Scenes();
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "floor", MakePose(0, 0, 0)).ok());
  const v1::Scene before = GetScene(*scenes, "default");
  const std::string obj = TetrahedraObj(400);  // 1600 triangles, ~60 KB
  const auto requests = Upload("partial", obj, 1024);
  ASSERT_GT(requests.size(), 20u);

  // Cut after a third of the chunks, and after every chunk but before the
  // half-close (the server must not take "no more data yet" for the end).
  for (std::size_t sent : {requests.size() / 3, requests.size()}) {
    SCOPED_TRACE("chunks sent before cancel: " + std::to_string(sent));
    auto ctx = Ctx();
    v1::Body body;
    auto writer = scenes->AddBody(ctx.get(), &body);
    for (std::size_t i = 0; i < sent; ++i) ASSERT_TRUE(writer->Write(requests[i]));
    // Give the server time to take in what was sent before the client goes.
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    ctx->TryCancel();
    EXPECT_EQ(writer->Finish().error_code(), grpc::StatusCode::CANCELLED);
    ASSERT_TRUE(WaitUntil([&] { return h.server().counts().active_calls == 0; }))
        << "calls left: " << h.server().counts().active_calls;
    const v1::Scene after = GetScene(*scenes, "default");
    EXPECT_EQ(after.revision(), before.revision());
    ASSERT_EQ(after.bodies_size(), 1);
    EXPECT_EQ(after.bodies(0).body_id(), "floor");
  }

  // Healthy: the same upload, completed, lands whole.
  v1::Body body;
  const grpc::Status s = AddBodyRaw(*scenes, requests, &body);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(body.body_id(), "partial");
  EXPECT_EQ(body.mesh_info().triangles(), 1600u);
  EXPECT_EQ(GetScene(*scenes, "default").bodies_size(), 2);
}

TEST(Faults, ObserverThatNeverReadsDoesNotStallSessionsOrObservers) {
  ServerHarness h(Transport::kTcp);
  auto scenes = h.Scenes();
  // Many bodies make pose frames big, so the idle reader's transport window
  // fills quickly.
  for (int i = 0; i < 60; ++i) {
    ASSERT_TRUE(AddShape(*scenes, "default", "box:0.01,0.01,0.01", "b" + std::to_string(i),
                         MakePose(1 + 0.03 * i, 0, 0), true)
                    .ok());
  }
  ASSERT_TRUE(AddShape(*scenes, "default", "box:0.05,0.05,0.05", "floor", MakePose(0, 0, 0)).ok());
  // Never reads: not even the snapshot.
  auto idle_ctx = Ctx();
  v1::WatchRequest wr;
  wr.set_scene_id("default");
  wr.set_rate_hz(1000);
  wr.set_include_meshes(true);
  auto idle = scenes->Watch(idle_ctx.get(), wr);
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().observer_frames_dropped > 0; },
                        std::chrono::seconds(60)))
      << "an observer that never reads never had a frame dropped";

  // A second observer reads on its own thread.
  std::atomic<int> frames{0};
  auto other_ctx = Ctx();
  wr.set_rate_hz(100);
  wr.set_include_meshes(false);
  auto other = scenes->Watch(other_ctx.get(), wr);
  std::thread reader([&] {
    v1::SceneEvent ev;
    while (other->Read(&ev)) {
      if (ev.has_poses()) ++frames;
    }
  });

  // A device session gets every pose answered, while bodies keep moving.
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  for (std::uint64_t k = 1; k <= 300; ++k) {
    if (k % 30 == 0) {
      v1::MoveBodyRequest mv;
      mv.set_scene_id("default");
      mv.set_body_id("b" + std::to_string(k / 30));
      *mv.mutable_pose() = MakePose(1 + 0.001 * k, 0.5, 0);
      v1::MoveBodyResponse mr;
      auto ctx = Ctx();
      ASSERT_TRUE(scenes->MoveBody(ctx.get(), mv, &mr).ok());
    }
    ASSERT_TRUE(s.Send(k, MakePose(0, 0, 0.055)));
    const auto u = s.Next();
    ASSERT_TRUE(u);
    ASSERT_EQ(u->sequence(), k);
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
  }
  EXPECT_TRUE(WaitUntil([&] { return frames.load() >= 5; })) << "frames: " << frames.load();
  s.CloseWrites();
  EXPECT_FALSE(s.Next());
  EXPECT_TRUE(s.Finish().ok());

  other_ctx->TryCancel();
  reader.join();
  other->Finish();
  idle_ctx->TryCancel();
  idle->Finish();
  EXPECT_TRUE(WaitUntil([&] { return h.server().counts().active_calls == 0; }));
  EXPECT_EQ(h.server().counts().observers, 0);
}

}  // namespace
}  // namespace hapticpd::testing
