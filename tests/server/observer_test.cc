// Watch over both transports: snapshot first, then changes and poses; an
// injected body shows up in the next PD answer and in observers' streams; a
// slow observer drops frames without slowing a device session or another
// observer; one publisher per scene; the observer limit.
#include <atomic>
#include <map>
#include <set>
#include <thread>

#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {

class ObserverTest : public ::testing::TestWithParam<Transport> {};

/// An observer reading on its own thread and counting what it sees.
class Observer {
 public:
  Observer(v1::SceneService::Stub& stub, const std::string& scene, double rate_hz, bool read = true)
      : ctx_(Ctx()) {
    v1::WatchRequest req;
    req.set_scene_id(scene);
    req.set_rate_hz(rate_hz);
    reader_ = stub.Watch(ctx_.get(), req);
    if (read) thread_ = std::thread([this] { Loop(); });
  }
  ~Observer() { Stop(); }

  /// Reads one event on the caller's thread (only without the reader thread).
  bool ReadOne(v1::SceneEvent* ev) { return reader_->Read(ev); }

  /// Ends the stream; `cancel` = false only once the server has ended it.
  void Stop(bool cancel = true) {
    if (stopped_) return;
    stopped_ = true;
    if (cancel) ctx_->TryCancel();
    if (thread_.joinable()) thread_.join();
    status_ = reader_->Finish();
  }

  int pose_frames() const { return pose_frames_.load(); }
  bool saw_added(const std::string& id) const {
    std::lock_guard lock(mu_);
    return added_.count(id) > 0;
  }
  bool saw_removed(const std::string& id) const {
    std::lock_guard lock(mu_);
    return removed_.count(id) > 0;
  }
  bool saw_probe() const { return saw_probe_.load(); }
  bool first_was_snapshot() const { return first_snapshot_.load(); }
  double last_pose_x(const std::string& id) const {
    std::lock_guard lock(mu_);
    auto it = last_x_.find(id);
    return it == last_x_.end() ? std::nan("") : it->second;
  }
  const grpc::Status& status() const { return status_; }

 private:
  void Loop() {
    v1::SceneEvent ev;
    bool first = true;
    while (reader_->Read(&ev)) {
      std::lock_guard lock(mu_);
      if (first) first_snapshot_ = ev.has_snapshot();
      first = false;
      if (ev.has_snapshot()) {
        for (const auto& b : ev.snapshot().bodies()) added_.insert(b.body_id());
      }
      if (ev.has_changes()) {
        for (const auto& b : ev.changes().added()) added_.insert(b.body_id());
        for (const auto& id : ev.changes().removed()) removed_.insert(id);
      }
      if (ev.has_poses()) {
        ++pose_frames_;
        for (const auto& b : ev.poses().bodies()) last_x_[b.body_id()] = b.pose().position().x();
        if (ev.poses().probes_size() > 0) saw_probe_ = true;
      }
    }
  }

  std::unique_ptr<grpc::ClientContext> ctx_;
  std::unique_ptr<grpc::ClientReader<v1::SceneEvent>> reader_;
  std::thread thread_;
  bool stopped_ = false;
  grpc::Status status_;
  mutable std::mutex mu_;
  std::set<std::string> added_, removed_;
  std::map<std::string, double> last_x_;
  std::atomic<int> pose_frames_{0};
  std::atomic<bool> saw_probe_{false};
  std::atomic<bool> first_snapshot_{false};
};

TEST_P(ObserverTest, SnapshotThenChangesAndPoses) {
  ServerHarness h(GetParam());
  auto scenes = h.Scenes();
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "a", MakePose(0, 0, 0), true).ok());
  Observer obs(*scenes, "default", 200);
  ASSERT_TRUE(WaitUntil([&] { return obs.saw_added("a") && obs.pose_frames() > 0; }));
  EXPECT_TRUE(obs.first_was_snapshot());
  ASSERT_TRUE(AddShape(*scenes, "default", "box", "b", MakePose(1, 0, 0)).ok());
  ASSERT_TRUE(WaitUntil([&] { return obs.saw_added("b"); }));
  ASSERT_TRUE(MoveBody(*scenes, "default", "a", MakePose(0.25, 0, 0)).ok());
  ASSERT_TRUE(WaitUntil([&] { return obs.last_pose_x("a") == 0.25; }));
  ASSERT_TRUE(RemoveBody(*scenes, "default", "b").ok());
  ASSERT_TRUE(WaitUntil([&] { return obs.saw_removed("b"); }));
  // A device session's probe shows up in pose frames.
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  ASSERT_TRUE(s.Send(1, MakePose(0, 0, 0.5)));
  ASSERT_TRUE(s.Next());
  EXPECT_TRUE(WaitUntil([&] { return obs.saw_probe(); }));
}

TEST_P(ObserverTest, InjectedBodyAppearsInTheNextPdAnswerAndInObservers) {
  ServerHarness h(GetParam());
  auto scenes = h.Scenes();
  Observer obs(*scenes, "default", 60);
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  const v1::Pose at = MakePose(0.3, 0.1, 0.2);
  ASSERT_TRUE(s.Send(1, at));
  auto u = s.Next();
  ASSERT_TRUE(u);
  EXPECT_EQ(u->status(), v1::CONTACT_STATUS_SEPARATED);
  // Inject a box around the probe: the very next answer must see it.
  ASSERT_TRUE(
      AddShape(*scenes, "default", "box:0.05,0.05,0.05", "wall", MakePose(0.3, 0.1, 0.16)).ok());
  ASSERT_TRUE(s.Send(2, at));
  u = s.Next();
  ASSERT_TRUE(u);
  EXPECT_EQ(u->sequence(), 2u);
  EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
  ASSERT_EQ(u->body_ids_size(), 1);
  EXPECT_EQ(u->body_ids(0), "wall");
  EXPECT_GT(u->force().z(), 0);
  EXPECT_TRUE(WaitUntil([&] { return obs.saw_added("wall"); }));
  // And removal: gone from the next answer.
  ASSERT_TRUE(RemoveBody(*scenes, "default", "wall").ok());
  ASSERT_TRUE(s.Send(3, at));
  u = s.Next();
  ASSERT_TRUE(u);
  EXPECT_EQ(u->status(), v1::CONTACT_STATUS_SEPARATED);
  EXPECT_TRUE(WaitUntil([&] { return obs.saw_removed("wall"); }));
}

TEST_P(ObserverTest, SlowObserverDropsFramesWithoutSlowingOthers) {
  ServerHarness h(GetParam());
  auto scenes = h.Scenes();
  // Many bodies make pose frames big, so a stalled reader fills the
  // transport's buffers quickly.
  for (int i = 0; i < 60; ++i) {
    ASSERT_TRUE(AddShape(*scenes, "default", "box:0.01,0.01,0.01", "b" + std::to_string(i),
                         MakePose(1 + 0.03 * i, 0, 0))
                    .ok());
  }
  ASSERT_TRUE(AddShape(*scenes, "default", "box:0.05,0.05,0.05", "floor", MakePose(0, 0, 0)).ok());
  Observer slow(*scenes, "default", 1000, /*read=*/false);
  v1::SceneEvent first;
  ASSERT_TRUE(slow.ReadOne(&first));  // the snapshot, then it stops reading
  ASSERT_TRUE(first.has_snapshot());
  // The server notices the stalled observer: its frames are being dropped.
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().observer_frames_dropped > 0; },
                        std::chrono::seconds(60)))
      << "a stalled observer never had a frame dropped";
  Observer fast(*scenes, "default", 100);
  // A device session runs at full speed meanwhile: every pose answered.
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello()).ok());
  const auto dropped_before = h.server().counts().observer_frames_dropped;
  for (std::uint64_t k = 1; k <= 300; ++k) {
    ASSERT_TRUE(s.Send(k, MakePose(0, 0, 0.055)));
    const auto u = s.Next();
    ASSERT_TRUE(u);
    ASSERT_EQ(u->sequence(), k);
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_PENETRATING);
  }
  // The other observer kept receiving frames while the slow one stalled.
  EXPECT_TRUE(WaitUntil([&] { return fast.pose_frames() >= 5; }));
  EXPECT_TRUE(
      WaitUntil([&] { return h.server().counts().observer_frames_dropped > dropped_before; }));
  s.ExpectCleanEnd();
}

TEST_P(ObserverTest, EachSceneHasItsOwnPublisherReapedAfterTheSceneIsDeleted) {
  ServerHarness h(GetParam());
  auto scenes = h.Scenes();
  ASSERT_TRUE(CreateScene(*scenes, "other").ok());
  EXPECT_EQ(h.server().counts().publishers, 0);  // started by the first observer
  Observer a(*scenes, "default", 100);
  Observer b(*scenes, "other", 100);
  ASSERT_TRUE(WaitUntil([&] { return a.pose_frames() > 0 && b.pose_frames() > 0; }));
  EXPECT_EQ(h.server().counts().publishers, 2);
  // A change of one scene reaches that scene's observer.
  ASSERT_TRUE(AddShape(*scenes, "other", "box", "x", MakePose(0, 0, 0)).ok());
  ASSERT_TRUE(WaitUntil([&] { return b.saw_added("x"); }));
  EXPECT_FALSE(a.saw_added("x"));
  ASSERT_TRUE(DeleteScene(*scenes, "other").ok());
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().observers == 1; }));
  b.Stop(false);
  EXPECT_EQ(b.status().error_code(), grpc::StatusCode::NOT_FOUND);
  // The deleted scene's publisher is reaped when the next observer arrives.
  Observer c(*scenes, "default", 100);
  ASSERT_TRUE(WaitUntil([&] { return c.pose_frames() > 0; }));
  EXPECT_EQ(h.server().counts().publishers, 1);
  EXPECT_GT(a.pose_frames(), 0);
}

TEST_P(ObserverTest, ObserverLimitAndBadRequests) {
  server::ServerOptions opt;
  opt.limits.max_observers = 2;
  ServerHarness h(GetParam(), opt);
  auto scenes = h.Scenes();
  Observer a(*scenes, "default", 60), b(*scenes, "default", 60);
  ASSERT_TRUE(WaitUntil([&] { return a.pose_frames() > 0 && b.pose_frames() > 0; }));
  {
    Observer c(*scenes, "default", 60, false);
    v1::SceneEvent ev;
    EXPECT_FALSE(c.ReadOne(&ev));
    c.Stop(false);
    EXPECT_EQ(c.status().error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  }
  a.Stop();
  ASSERT_TRUE(WaitUntil([&] { return h.server().counts().observers == 1; }));
  for (double rate : {-1.0, 5000.0, std::nan("")}) {
    Observer bad(*scenes, "default", rate, false);
    v1::SceneEvent ev;
    EXPECT_FALSE(bad.ReadOne(&ev));
    bad.Stop(false);
    EXPECT_EQ(bad.status().error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(bad.status().error_message().find("rate_hz"), std::string::npos);
  }
  Observer nowhere(*scenes, "nowhere", 60, false);
  v1::SceneEvent ev;
  EXPECT_FALSE(nowhere.ReadOne(&ev));
  nowhere.Stop(false);
  EXPECT_EQ(nowhere.status().error_code(), grpc::StatusCode::NOT_FOUND);
}

INSTANTIATE_TEST_SUITE_P(Transports, ObserverTest,
                         ::testing::Values(Transport::kInProcess, Transport::kTcp), TransportName);

}  // namespace
}  // namespace hapticpd::testing
