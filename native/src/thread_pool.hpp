// A small persistent pool of worker threads for the compiled per-stage loops (stage_jacobian.cpp):
// made on first use, grown to the largest number of helpers asked for, never torn down (its threads
// wait on a condition variable between calls; a forked child makes its own). The caller runs one share
// of the work itself, so `helpers` extra threads make helpers + 1 workers.
#pragma once

#include <condition_variable>
#include <functional>
#include <mutex>

namespace pgpc {

class ThreadPool {
 public:
  // the process's pool (a new one in a forked child: the parent's threads do not exist there)
  static ThreadPool &shared();
  // task(0) on the calling thread and task(1..helpers) on the pool's threads at once; returns when task(0)
  // and the helpers that started have returned (a helper that had not started when task(0) returned
  // skips this call: task(0) must be able to finish the work alone). task must not throw on a helper (catch and hand the exception over: an exception that
  // leaves a helper thread ends the process); task(0)'s is rethrown after the helpers are done. Concurrent
  // calls take turns
  void run(int helpers, const std::function<void(int)> &task);
  // the cores free for helpers now: the CPUs this process may run on less the runnable tasks of the machine
  // (/proc/loadavg's fourth field, which counts the calling thread), sampled at most every 10 ms; a large
  // number where that cannot be read, or while adapt(false). A helper that has no core to itself makes a
  // call slower, not faster: the caller waits for it whenever the machine preempts it within a stage
  static int free_cores();
  // false: free_cores() does not look at the machine (tests that must exercise the helpers; benchmarks)
  static void adapt(bool on);
  ThreadPool(const ThreadPool &) = delete;
  ThreadPool &operator=(const ThreadPool &) = delete;

 private:
  ThreadPool() = default;
  void loop(int slot);

  std::mutex turn_;  // one run at a time
  std::mutex m_;
  std::condition_variable wake_, done_;
  int started_ = 0;  // threads started: slots 1..started_
  const std::function<void(int)> *task_ = nullptr;
  int helpers_ = 0, active_ = 0;  // helpers asked, helpers at work
  bool closed_ = false;           // task(0) has returned: no helper starts any more
  unsigned long generation_ = 0;
};

}  // namespace pgpc
