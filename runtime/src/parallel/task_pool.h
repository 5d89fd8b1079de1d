// A fixed pool of threads for the parallel stages of a frame (the texture
// force of a frame's patches). Not oneTBB: a frame has a handful of tasks of
// similar size (one per contact patch, tens to hundreds of microseconds
// each), and the pool must allocate nothing per frame and keep the same
// threads for the whole session (a real-time loop wants no thread creation,
// no work-stealing deques growing, no allocator in the frame). The workers
// are started once; run() wakes them, the calling thread works too, and
// run() returns when every task is done. Workers poll for a short while
// after a run before they sleep (task_pool.cpp, kSpin).
#pragma once

#include <atomic>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace hrt {

class TaskPool {
 public:
  // `threads` >= 1 threads in all, the caller of run() included (threads - 1
  // workers are started here).
  explicit TaskPool(int threads);
  ~TaskPool();
  TaskPool(const TaskPool&) = delete;
  TaskPool& operator=(const TaskPool&) = delete;

  int threads() const { return static_cast<int>(workers_.size()) + 1; }

  // Calls fn(task, slot) for every task in [0, count), each exactly once, on
  // the pool's threads and the caller's; `slot` in [0, threads()) names the
  // thread (the caller is 0) so that fn can use per-thread scratch. Which
  // thread runs which task is not fixed: fn's result must not depend on it.
  // The first exception a task throws is rethrown here once all tasks have
  // ended (the others still run). Not reentrant.
  template <class F>
  void run(int count, F& fn) {
    run_erased(count, &call<F>, &fn);
  }

 private:
  using Call = void (*)(void*, int, int);
  template <class F>
  static void call(void* ctx, int task, int slot) {
    (*static_cast<F*>(ctx))(task, slot);
  }
  void run_erased(int count, Call call, void* ctx);
  void work(int slot);
  void worker_main(int slot);

  std::vector<std::thread> workers_;
  std::mutex mutex_;  // the sleepers' condition variable, the first error
  std::condition_variable start_cv_;
  std::atomic<uint64_t> generation_{0};  // incremented by each run() with workers
  std::atomic<int> active_{0};           // workers still inside the current run
  std::atomic<bool> stop_{false};
  // The current job (written before the generation is published).
  Call call_ = nullptr;
  void* ctx_ = nullptr;
  int count_ = 0;
  std::atomic<int> next_{0};
  std::exception_ptr error_;  // the first task exception (under mutex_)
};

}  // namespace hrt
