// One control period of MuJoCo C for a batch of robots, as an XLA FFI handler.
//
// The native engine's host callback runs Python for every control period; at small batches
// that costs more than the physics.  This handler makes the same MuJoCo calls as the
// callback's mujoco.rollout (state set, warm start cleared, warning counters cleared, then
// per substep: stop at a warning, set the controls, mj_step) and the same divergence test,
// inside XLA's own call, with no Python.  mjxcpg/physics/native_step.py compiles and loads it.
// A large batch is split into contiguous blocks of rows, one per thread, each thread with its
// own mjData; every row's result is the same whichever thread steps it.

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include <mujoco/mujoco.h>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

bool AnyWarning(const mjData* d) {
  for (int i = 0; i < mjNWARNING; i++) {
    if (d->warning[i].number) return true;
  }
  return false;
}

// Threads kept between calls: starting one per control period costs tens of microseconds,
// and a worker that sleeps between periods must be woken.  A worker waits for the next call
// spinning for kSpin, then asleep; the calling thread runs block 0 and spins until the
// workers are done.
class Pool {
 public:
  // fn(k) for k in [0, blocks): k = 0 on the calling thread.  False if the workers could not
  // be started; then nothing has run.
  bool Run(int64_t blocks, const std::function<void(int64_t)>& fn) {
    try {
      // A new worker waits for the next call, not the one before it (calls are serialised,
      // so the generation does not move while workers are added).
      const uint64_t now = generation_.load(std::memory_order_acquire);
      while (static_cast<int64_t>(workers_.size()) < blocks - 1) {
        const int64_t index = workers_.size();
        workers_.emplace_back([this, index, now] { Work(index, now); });
      }
    } catch (const std::exception&) {
      return false;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      task_ = &fn;
      blocks_ = blocks;
      pending_.store(workers_.size(), std::memory_order_relaxed);
      generation_.fetch_add(1, std::memory_order_release);
    }
    wake_.notify_all();
    fn(0);
    while (pending_.load(std::memory_order_acquire) != 0) std::this_thread::yield();
    return true;
  }

 private:
  static constexpr std::chrono::microseconds kSpin{500};

  void Work(int64_t index, uint64_t seen) {
    for (;;) {
      const auto start = std::chrono::steady_clock::now();
      while (generation_.load(std::memory_order_acquire) == seen) {
        if (std::chrono::steady_clock::now() - start > kSpin) {
          std::unique_lock<std::mutex> lock(mutex_);
          wake_.wait(lock, [&] { return generation_.load(std::memory_order_acquire) != seen; });
        }
      }
      seen = generation_.load(std::memory_order_acquire);
      if (index + 1 < blocks_) (*task_)(index + 1);
      pending_.fetch_sub(1, std::memory_order_release);
    }
  }

  std::vector<std::thread> workers_;  // never joined: the pool lives as long as the process
  std::mutex mutex_;
  std::condition_variable wake_;
  std::atomic<uint64_t> generation_{0};
  std::atomic<int64_t> pending_{0};
  const std::function<void(int64_t)>* task_ = nullptr;
  int64_t blocks_ = 0;
};

// The rows ``rows[0..count)``, all active: the state after ``substeps`` steps under ``ctrl``
// (the servo targets), or NaN where MuJoCo diverged (its clock did not advance by the control
// period, or the state is not finite).
void StepRows(const mjModel* m, mjData* d, const int64_t* rows, int64_t count, int64_t substeps,
              int64_t force_address, int64_t velocity_address, const float* state_in, const float* ctrl_in,
              float* state_out, float* sensors_out, float* work_out) {
  const int nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS);
  const int nsensordata = m->nsensordata, nu = m->nu;
  std::vector<mjtNum> start(nstate), stepped(nstate), controls(nu);
  const double expected = substeps * m->opt.timestep;

  // The user inputs the controls do not set, cleared as rollout clears them.
  mju_zero(d->qfrc_applied, m->nv);
  mju_zero(d->xfrc_applied, 6 * m->nbody);
  for (int i = 0; i < m->neq; i++) d->eq_active[i] = m->eq_active0[i];

  for (int64_t j = 0; j < count; j++) {
    const int64_t r = rows[j];
    float* row_out = state_out + r * nstate;
    float* sensors_row_out = sensors_out + r * nsensordata;
    for (int i = 0; i < nstate; i++) start[i] = state_in[r * nstate + i];
    for (int i = 0; i < nu; i++) controls[i] = ctrl_in[r * nu + i];
    mj_setState(m, d, start.data(), mjSTATE_FULLPHYSICS);
    mju_zero(d->qacc_warmstart, m->nv);
    for (int i = 0; i < mjNWARNING; i++) d->warning[i].number = 0;
    double work = 0.0;
    for (int64_t t = 0; t < substeps && !AnyWarning(d); t++) {
      mj_setState(m, d, controls.data(), mjSTATE_CTRL);
      mj_step(m, d);
      // model.positive_power: sum over actuators of max(0, force x velocity), times the step.
      for (int i = 0; i < nu; i++) {
        work += std::max(0.0, d->sensordata[force_address + i] * d->sensordata[velocity_address + i]) *
                m->opt.timestep;
      }
    }
    mj_getState(m, d, stepped.data(), mjSTATE_FULLPHYSICS);
    double sum = 0.0;
    for (int i = 0; i < nstate; i++) sum += stepped[i];
    const bool on_time = std::fabs(stepped[0] - start[0] - expected) <= 1e-6 + 1e-3 * expected;
    const bool diverged = !on_time || !std::isfinite(sum);
    for (int i = 0; i < nstate; i++) row_out[i] = diverged ? NAN : static_cast<float>(stepped[i]);
    for (int i = 0; i < nsensordata; i++) {
      sensors_row_out[i] = diverged ? NAN : static_cast<float>(d->sensordata[i]);
    }
    work_out[r] = diverged ? NAN : static_cast<float>(work);
  }
}

// ``datas``: the address of an array of ``threads`` mjData addresses.  Rows without ``active``
// keep their values (the outputs alias the inputs, else they are copied).  The active rows
// are split into ``threads`` blocks of nearly equal size, stepped by the calling thread and
// the pool's, or all by the calling thread if the pool's cannot be started: a batch whose
// finished learners sit in one part of it still keeps every thread busy.  Calls are
// serialised: they share the mjData and the pool.
ffi::Error Step(ffi::Buffer<ffi::F32> physics, ffi::Buffer<ffi::F32> sensordata, ffi::Buffer<ffi::F32> work,
                ffi::Buffer<ffi::F32> ctrl, ffi::Buffer<ffi::PRED> active,
                ffi::ResultBuffer<ffi::F32> physics_out, ffi::ResultBuffer<ffi::F32> sensordata_out,
                ffi::ResultBuffer<ffi::F32> work_out, int64_t model_address, int64_t datas, int64_t threads,
                int64_t substeps, int64_t force_address, int64_t velocity_address) {
  static std::mutex one_call_at_a_time;
  std::lock_guard<std::mutex> lock(one_call_at_a_time);
  const mjModel* m = reinterpret_cast<const mjModel*>(model_address);
  mjData* const* data = reinterpret_cast<mjData* const*>(datas);
  const int64_t batch = active.element_count();
  const int nstate = mj_stateSize(m, mjSTATE_FULLPHYSICS), nsensordata = m->nsensordata;
  if (physics.element_count() != batch * nstate || sensordata.element_count() != batch * nsensordata ||
      work.element_count() != batch || ctrl.element_count() != batch * m->nu ||
      force_address < 0 || velocity_address < 0 || force_address + m->nu > nsensordata ||
      velocity_address + m->nu > nsensordata) {
    return ffi::Error::InvalidArgument("mjxcpg_mujoco_step: buffer sizes do not match the model");
  }
  if (physics_out->typed_data() != physics.typed_data()) {
    std::copy(physics.typed_data(), physics.typed_data() + batch * nstate, physics_out->typed_data());
  }
  if (sensordata_out->typed_data() != sensordata.typed_data()) {
    std::copy(sensordata.typed_data(), sensordata.typed_data() + batch * nsensordata,
              sensordata_out->typed_data());
  }
  if (work_out->typed_data() != work.typed_data()) {
    std::copy(work.typed_data(), work.typed_data() + batch, work_out->typed_data());
  }
  std::vector<int64_t> live;
  for (int64_t r = 0; r < batch; r++) {
    if (active.typed_data()[r]) live.push_back(r);
  }
  const int64_t count = live.size();
  const int64_t blocks = std::max<int64_t>(1, std::min(threads, count));
  std::atomic<bool> failed{false};
  auto block = [&](int64_t k) {
    try {
      const int64_t first = count * k / blocks, last = count * (k + 1) / blocks;
      StepRows(m, data[k], live.data() + first, last - first, substeps, force_address, velocity_address,
               physics.typed_data(), ctrl.typed_data(), physics_out->typed_data(),
               sensordata_out->typed_data(), work_out->typed_data());
    } catch (const std::exception&) {
      failed = true;
    }
  };
  static Pool* pool = new Pool();  // leaked on purpose: its threads never end
  const std::function<void(int64_t)> task = block;
  if (blocks == 1 || !pool->Run(blocks, task)) {
    for (int64_t k = 0; k < blocks; k++) block(k);  // no threads to be had: all on this one
  }
  if (failed) return ffi::Error::Internal("mjxcpg_mujoco_step: stepping a block of robots failed");
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(MjxcpgMujocoStep, Step,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::PRED>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Attr<int64_t>("model")
                                  .Attr<int64_t>("datas")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("substeps")
                                  .Attr<int64_t>("force_address")
                                  .Attr<int64_t>("velocity_address"));
