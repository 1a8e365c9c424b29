// A bounded single-producer / single-consumer queue (a ring of fixed
// capacity, allocated once at construction). Push and Pop are wait-free:
// one thread pushes (the servo loop, a PD worker), another pops (the
// session's telemetry step, an observer publisher). A push into a full ring
// is refused and counted (lost()), never blocks and never overwrites what
// the consumer has not taken. Header-only and free of other project
// dependencies, so the server uses it too.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace hapticpd::device {

template <typename T>
class SpscRing {
 public:
  /// `capacity` >= 1 values; allocated here, never again.
  explicit SpscRing(std::size_t capacity) : slots_(capacity > 0 ? capacity : 1) {}
  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;

  std::size_t capacity() const { return slots_.size(); }

  // --- producer side
  /// Appends `value`; false (counted in lost()) when the ring is full.
  bool Push(const T& value) {
    const std::uint64_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_.load(std::memory_order_acquire) >= slots_.size()) {
      lost_.fetch_add(1, std::memory_order_relaxed);
      return false;
    }
    slots_[head % slots_.size()] = value;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  // --- consumer side
  /// Takes the oldest value; false when the ring is empty.
  bool Pop(T* out) {
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_.load(std::memory_order_acquire)) return false;
    *out = slots_[tail % slots_.size()];
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }

  // --- any thread
  /// Values refused because the ring was full (cumulative).
  std::uint64_t lost() const { return lost_.load(std::memory_order_relaxed); }
  /// Values pushed so far (cumulative).
  std::uint64_t pushed() const { return head_.load(std::memory_order_relaxed); }
  /// Values waiting (a snapshot; exact only on the consumer's thread when
  /// the producer is idle).
  std::size_t size() const {
    return static_cast<std::size_t>(head_.load(std::memory_order_acquire) -
                                    tail_.load(std::memory_order_acquire));
  }

 private:
  std::vector<T> slots_;
  alignas(64) std::atomic<std::uint64_t> head_{0};  // written by the producer
  alignas(64) std::atomic<std::uint64_t> tail_{0};  // written by the consumer
  alignas(64) std::atomic<std::uint64_t> lost_{0};
};

}  // namespace hapticpd::device
