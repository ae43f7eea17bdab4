// The persistent worker threads of the compiled per-stage loops (thread_pool.hpp).
#include "thread_pool.hpp"

#include <atomic>
#include <chrono>
#include <climits>
#include <cstdio>
#include <exception>
#include <thread>

#if defined(_WIN32)
#include <process.h>
#define getpid _getpid
#else
#include <unistd.h>
#endif
#if defined(__linux__)
#include <sched.h>
#endif

namespace pgpc {

namespace {
std::atomic<bool> adapting{true};
std::atomic<long> sampled_at{-1};  // steady clock, µs; −1: not sampled
std::atomic<int> sampled_free{INT_MAX};

int runnable_tasks() {  // of /proc/loadavg ("0.52 0.58 0.59 3/146 9061"), or -1 (not Linux)
  std::FILE *f = std::fopen("/proc/loadavg", "r");
  if (f == nullptr) return -1;
  double a, b, c;
  int running = -1, total = 0;
  if (std::fscanf(f, "%lf %lf %lf %d/%d", &a, &b, &c, &running, &total) != 5) running = -1;
  std::fclose(f);
  return running;
}

int usable_cpus() {
#if defined(__linux__)
  cpu_set_t set;
  if (sched_getaffinity(0, sizeof(set), &set) == 0) return CPU_COUNT(&set);
#endif
  const unsigned n = std::thread::hardware_concurrency();
  return n > 0 ? static_cast<int>(n) : 1;
}
}  // namespace

int ThreadPool::free_cores() {
  if (!adapting.load(std::memory_order_relaxed)) return INT_MAX;
  const long now = std::chrono::duration_cast<std::chrono::microseconds>(
                       std::chrono::steady_clock::now().time_since_epoch()).count();
  const long at = sampled_at.load(std::memory_order_relaxed);
  if (at >= 0 && now - at < 10000) return sampled_free.load(std::memory_order_relaxed);
  static const int cpus = usable_cpus();
  const int running = runnable_tasks();
  const int free = running < 0 ? INT_MAX : cpus - running;  // the caller is one of the running
  sampled_free.store(free, std::memory_order_relaxed);
  sampled_at.store(now, std::memory_order_relaxed);
  return free;
}

void ThreadPool::adapt(bool on) {
  adapting.store(on);
  sampled_at.store(-1);
}

ThreadPool &ThreadPool::shared() {
  static std::mutex made;
  static ThreadPool *pool = nullptr;  // never deleted: no join at exit, while the interpreter winds down
  static long owner = 0;
  std::lock_guard<std::mutex> lock(made);
  if (pool == nullptr || owner != static_cast<long>(getpid())) {  // a forked child: the parent's pool is left as it is
    pool = new ThreadPool();
    owner = static_cast<long>(getpid());
  }
  return *pool;
}

void ThreadPool::loop(int slot) {
  unsigned long seen = 0;
  for (;;) {
    std::unique_lock<std::mutex> lock(m_);
    wake_.wait(lock, [&] { return generation_ != seen; });
    seen = generation_;
    if (closed_ || slot > helpers_) continue;  // woken after the caller finished its share, or not asked
    ++active_;
    const std::function<void(int)> *task = task_;
    lock.unlock();
    (*task)(slot);
    lock.lock();
    if (--active_ == 0) done_.notify_one();
  }
}

void ThreadPool::run(int helpers, const std::function<void(int)> &task) {
  std::lock_guard<std::mutex> turn(turn_);
  {
    std::lock_guard<std::mutex> lock(m_);
    for (; started_ < helpers; ++started_) {  // detached: they live as long as the process
      const int slot = started_ + 1;
      std::thread([this, slot] { loop(slot); }).detach();
    }
    task_ = &task;
    helpers_ = helpers;
    closed_ = false;
    ++generation_;
  }
  wake_.notify_all();
  std::exception_ptr own;  // the helpers use task until they are done: wait for them in any case
  try {
    task(0);
  } catch (...) {
    own = std::current_exception();
  }
  // a helper the machine has not run yet does not start now (the caller waits only for those at work):
  // task must leave nothing undone when some helpers never run it (stage_jacobian.cpp hands out its
  // stages from a shared counter)
  std::unique_lock<std::mutex> lock(m_);
  closed_ = true;
  done_.wait(lock, [&] { return active_ == 0; });
  task_ = nullptr;
  if (own) std::rethrow_exception(own);
}

}  // namespace pgpc
