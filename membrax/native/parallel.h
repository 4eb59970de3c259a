// Two-way parallel loops on XLA's intra-op thread pool, for the backward kernels: XLA:CPU runs the reverse
// pass's kernels one after another (it runs the forward's independent kernels side by side), so without
// this the second core idles through them (README, "where the time went").
//
// two_halves(pool, n, body) runs body(0, 0, n/2) on the calling thread and offers body(1, n/2, n) to the pool
// (xla::ffi::ThreadPool, the pool XLA:CPU runs its own parallel work on). Whichever thread claims the
// second half first runs it; if no pool thread has claimed it when the caller finishes the first, the
// caller runs it too. So the caller waits only for a half that is already running: no deadlock when the
// pool is busy, has one thread, or runs tasks in the caller (FFI's contract allows all three). The halves
// are fixed index ranges, so a body that writes per-index outputs and sums each half in order gives the
// same bits whichever thread ran which half; below kMinParallelElements the caller runs the same two
// halves itself, so small and large inputs sum alike.

#ifndef MEMBRAX_PARALLEL_H_
#define MEMBRAX_PARALLEL_H_

#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>

#include "xla/ffi/api/ffi.h"

namespace membrax {

// Below this many elements a half is too short to pay for the hand-off (a few microseconds).
inline constexpr int64_t kMinParallelElements = 4096;

template <typename Body>
void two_halves(xla::ffi::ThreadPool& pool, int64_t n, const Body& body) {
  const int64_t middle = n / 2;
  if (n < kMinParallelElements) {
    body(0, int64_t(0), middle);
    body(1, middle, n);
    return;
  }
  // 0: unclaimed, 1: claimed, 2: done. Shared, so a task that starts after the caller has returned
  // finds the half claimed and touches nothing else.
  auto state = std::make_shared<std::atomic<int>>(0);
  const Body* second = &body;
  pool.Schedule([state, second, middle, n]() {
    int unclaimed = 0;
    if (state->compare_exchange_strong(unclaimed, 1, std::memory_order_acq_rel)) {
      (*second)(1, middle, n);
      state->store(2, std::memory_order_release);
    }
  });
  body(0, int64_t(0), middle);
  int unclaimed = 0;
  if (state->compare_exchange_strong(unclaimed, 1, std::memory_order_acq_rel)) {
    body(1, middle, n);
    return;
  }
  while (state->load(std::memory_order_acquire) != 2) std::this_thread::yield();
}

}  // namespace membrax

#endif  // MEMBRAX_PARALLEL_H_
