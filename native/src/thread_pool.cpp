// The persistent worker threads of the compiled per-stage loops (thread_pool.hpp).
#include "thread_pool.hpp"

#include <exception>
#include <thread>

#include <unistd.h>

namespace pgpc {

ThreadPool &ThreadPool::shared() {
  static std::mutex made;
  static ThreadPool *pool = nullptr;  // never deleted: no join at exit, while the interpreter winds down
  static pid_t owner = 0;
  std::lock_guard<std::mutex> lock(made);
  if (pool == nullptr || owner != getpid()) {  // a forked child: the parent's pool is left as it is
    pool = new ThreadPool();
    owner = getpid();
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
