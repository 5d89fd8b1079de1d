#include "parallel/task_pool.h"

#include <algorithm>
#include <chrono>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define HRT_PAUSE() _mm_pause()
#else
#define HRT_PAUSE() ((void)0)
#endif

#include "hrt/scene.h"

namespace hrt {

namespace {
// How long a worker keeps polling for the next run before it sleeps on the
// condition variable. A frame hands out work every millisecond or so, and a
// wake-up through the kernel costs tens of microseconds on a loaded or
// virtualized machine (more than a whole task of a small patch), so workers
// poll for a while after each run; a pool left idle sleeps.
constexpr auto kSpin = std::chrono::microseconds(200);
}  // namespace

TaskPool::TaskPool(int threads) {
  const int workers = std::max(1, threads) - 1;
  workers_.reserve(static_cast<size_t>(workers));
  for (int w = 0; w < workers; ++w) workers_.emplace_back([this, w] { worker_main(w + 1); });
}

TaskPool::~TaskPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_.store(true);
  }
  start_cv_.notify_all();
  for (std::thread& t : workers_) t.join();
}

int resolve_threads(int requested) {
  if (requested >= 1) return requested;
  const unsigned hw = std::thread::hardware_concurrency();
  return hw == 0 ? 1 : static_cast<int>(hw);
}

void TaskPool::work(int slot) {
  for (;;) {
    const int task = next_.fetch_add(1, std::memory_order_relaxed);
    if (task >= count_) return;
    try {
      call_(ctx_, task, slot);
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!error_) error_ = std::current_exception();
    }
  }
}

void TaskPool::worker_main(int slot) {
  uint64_t seen = 0;
  for (;;) {
    // Poll, then sleep.
    const auto until = std::chrono::steady_clock::now() + kSpin;
    int polls = 0;
    while (generation_.load(std::memory_order_acquire) == seen && !stop_.load(std::memory_order_acquire)) {
      HRT_PAUSE();
      if (++polls % 64 == 0 && std::chrono::steady_clock::now() > until) {
        std::unique_lock<std::mutex> lock(mutex_);
        start_cv_.wait(lock, [&] { return stop_.load() || generation_.load() != seen; });
        break;
      }
    }
    if (stop_.load(std::memory_order_acquire)) return;
    seen = generation_.load(std::memory_order_acquire);
    work(slot);
    active_.fetch_sub(1, std::memory_order_acq_rel);
  }
}

void TaskPool::run_erased(int count, Call call, void* ctx) {
  if (count <= 0) return;
  if (workers_.empty() || count == 1) {  // nothing to share: no wake-up cost
    for (int k = 0; k < count; ++k) call(ctx, k, 0);
    return;
  }
  call_ = call;
  ctx_ = ctx;
  count_ = count;
  error_ = nullptr;
  next_.store(0, std::memory_order_relaxed);
  active_.store(static_cast<int>(workers_.size()), std::memory_order_relaxed);
  {
    // Under the mutex: a worker about to sleep checks the generation under
    // it, so the notification cannot fall between its check and its wait.
    std::lock_guard<std::mutex> lock(mutex_);
    generation_.fetch_add(1, std::memory_order_acq_rel);
  }
  start_cv_.notify_all();
  work(0);
  // The workers are inside this run (or about to leave it): wait for them.
  int polls = 0;
  while (active_.load(std::memory_order_acquire) != 0) {
    HRT_PAUSE();
    if (++polls % 256 == 0) std::this_thread::yield();
  }
  std::exception_ptr error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    error = error_;
    error_ = nullptr;
  }
  if (error) std::rethrow_exception(error);
}

}  // namespace hrt
