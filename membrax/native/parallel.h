// The kernels' use of XLA's intra-op thread pool (xla::ffi::ThreadPool, the pool XLA:CPU runs its own
// parallel work on), in two ways:
//
// on_pool(pool, elements, work), for the forward kernels: the handler checks its arguments, then runs
// work() as a pool task and returns a future (an asynchronous FFI handler; below kMinAsyncElements
// elements it runs work() itself). XLA's executor goes on meanwhile with the other operations that
// are ready, such as an independent kernel: the membrane forces, the node–sphere law and the sphere
// pairs of one step run side by side. Without it XLA ran them one after another in the recomputation
// of a checkpointed window, and the sphere pairs alone everywhere (docs/gradients.md). The
// arithmetic is unchanged, so are the bits.
//
// two_halves(pool, n, body), for the backward kernels, which XLA runs one after another and whose
// element loops are long: body(0, 0, n/2) runs on the calling thread and body(1, n/2, n) is offered to
// the pool. Whichever thread claims the second half first runs it; if no pool thread has claimed it
// when the caller finishes the first, the caller runs it too. So the caller waits only for a half that
// is already running: no deadlock when the pool is busy, has one thread, or runs tasks in the caller
// (FFI's contract allows all three). The halves are fixed index ranges, so a body that writes
// per-index outputs and sums each half in order gives the same bits whichever thread ran which half;
// below kMinParallelElements the caller runs the same two halves itself, so small and large inputs sum
// alike. halves_on_pool (below) is the same split for a forward kernel, without a waiting thread.

#ifndef MEMBRAX_PARALLEL_H_
#define MEMBRAX_PARALLEL_H_

#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string_view>
#include <thread>
#include <utility>

#include "xla/ffi/api/ffi.h"

namespace membrax {

// Below this many elements a half is too short to pay for the hand-off (a few microseconds).
inline constexpr int64_t kMinParallelElements = 4096;

// Whether the kernels hand work to the pool: not where the environment sets MEMBRAX_NATIVE_THREADS=1 (read
// once), and then every kernel runs its loops in the caller as below the thresholds, the same halves in
// the same order: the serial path that the tests hold the threaded one to, bit for bit.
inline bool pool_allowed() {
  static const bool allowed = [] {
    const char* threads = std::getenv("MEMBRAX_NATIVE_THREADS");
    return threads == nullptr || std::string_view(threads) != "1";
  }();
  return allowed;
}

template <typename Body>
void two_halves(xla::ffi::ThreadPool& pool, int64_t n, const Body& body) {
  const int64_t middle = n / 2;
  if (n < kMinParallelElements || !pool_allowed()) {
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

// Below this many elements a kernel runs in the caller: the hand-off to a pool thread costs more than
// running beside the other kernels saves (Table 1's nine members at the small size, 1,539 nodes, ran
// 4–18 % slower with every kernel handed off; at paper size the smallest loop has 11,865 pair slots).
inline constexpr int64_t kMinAsyncElements = 8192;

// Runs work() as a pool task and returns the future that XLA's executor waits on; for fewer than
// kMinAsyncElements elements, runs it here and returns a completed future. work() must touch only what
// outlives the handler's return: the buffers' data and values captured by copy, not the handler's
// Buffer objects or the pool (both are views of the call, which ends before the task does).
template <typename Work>
xla::ffi::Future on_pool(xla::ffi::ThreadPool& pool, int64_t elements, Work work) {
  xla::ffi::Promise promise;
  xla::ffi::Future future(promise);
  if (elements < kMinAsyncElements || !pool_allowed()) {
    work();
    promise.SetAvailable();
    return future;
  }
  pool.Schedule([promise, work]() mutable {
    work();
    promise.SetAvailable();
  });
  return future;
}

// The element range [begin, end) of half `half` (0 or 1) of n elements, as two_halves splits them.
struct Range {
  int64_t begin, end;
};
inline Range half_range(int half, int64_t n) { return half == 0 ? Range{0, n / 2} : Range{n / 2, n}; }

// two_halves for a forward (asynchronous) kernel, whose loops run as pool tasks: half(0) and half(1) are
// scheduled as two tasks and tail() runs once both are done, on the thread that finished last, which then
// completes the returned future; no thread waits for another. Below kMinAsyncElements elements the caller
// runs half(0), half(1) and tail() itself, in that order. Each half works on fixed ranges (half_range) and
// writes its own outputs; tail() does the sums across them in a fixed order, so the bits do not depend on
// which thread ran what. The rule of on_pool's work() holds for half, tail and what they capture.
template <typename Half, typename Tail>
xla::ffi::Future halves_on_pool(xla::ffi::ThreadPool& pool, int64_t elements, Half half, Tail tail) {
  xla::ffi::Promise promise;
  xla::ffi::Future future(promise);
  if (elements < kMinAsyncElements || !pool_allowed()) {
    half(0);
    half(1);
    tail();
    promise.SetAvailable();
    return future;
  }
  struct Shared {
    Half half;
    Tail tail;
    xla::ffi::Promise promise;
    std::atomic<int> finished{0};
  };
  std::shared_ptr<Shared> shared(new Shared{std::move(half), std::move(tail), promise});
  for (int h = 0; h < 2; ++h) {
    pool.Schedule([shared, h]() {
      shared->half(h);
      if (shared->finished.fetch_add(1, std::memory_order_acq_rel) == 1) {  // the other half is done
        shared->tail();
        shared->promise.SetAvailable();
      }
    });
  }
  return future;
}

// A future that has already failed with error (a handler's argument checks).
inline xla::ffi::Future failed(xla::ffi::Error error) {
  xla::ffi::Promise promise;
  xla::ffi::Future future(promise);
  promise.SetError(std::move(error));
  return future;
}

}  // namespace membrax

#endif  // MEMBRAX_PARALLEL_H_
