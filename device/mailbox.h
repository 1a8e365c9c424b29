// A single-writer / single-reader "latest value" mailbox (triple buffer).
//
// The writer fills its private back slot and publishes it by swapping it
// with the middle slot; the reader, when something new was published, swaps
// its front slot with the middle one. Both sides are wait-free (one atomic
// exchange), never block each other, and never copy under a lock, so the
// servo thread can read IRs and publish proxy poses at 1 kHz while a
// network or PD thread works at its own pace. Older values that were never
// read are overwritten: it carries the newest value, not a queue.
//
// T must be default-constructible and copy-assignable. Exactly one thread may
// call the writer methods and exactly one (possibly another) the reader
// methods.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>

namespace hapticpd::device {

template <typename T>
class LatestMailbox {
 public:
  LatestMailbox() = default;
  LatestMailbox(const LatestMailbox&) = delete;
  LatestMailbox& operator=(const LatestMailbox&) = delete;

  // --- writer side
  /// The slot to fill before Publish() (owned by the writer until then).
  T& back() { return slots_[back_]; }
  /// Makes back() the newest value and hands the writer a fresh back slot.
  void Publish() {
    const std::uint8_t prev =
        middle_.exchange(static_cast<std::uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = prev & kIndexMask;
    published_.fetch_add(1, std::memory_order_relaxed);
  }
  /// Copies `value` into the back slot and publishes it.
  void Write(const T& value) {
    back() = value;
    Publish();
  }

  // --- reader side
  /// Takes the newest published value if there is one the reader has not
  /// seen; returns true then. front() holds the newest value taken so far.
  bool Fetch() {
    if ((middle_.load(std::memory_order_relaxed) & kFresh) == 0) return false;
    const std::uint8_t prev = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = prev & kIndexMask;
    return true;
  }
  const T& front() const { return slots_[front_]; }
  T& front() { return slots_[front_]; }

  /// Values published so far (any thread; for statistics).
  std::uint64_t published() const { return published_.load(std::memory_order_relaxed); }

 private:
  static constexpr std::uint8_t kFresh = 0x4;
  static constexpr std::uint8_t kIndexMask = 0x3;
  std::array<T, 3> slots_{};
  std::uint8_t back_ = 0;   // writer-owned
  std::uint8_t front_ = 1;  // reader-owned
  std::atomic<std::uint8_t> middle_{2};
  std::atomic<std::uint64_t> published_{0};
};

}  // namespace hapticpd::device
