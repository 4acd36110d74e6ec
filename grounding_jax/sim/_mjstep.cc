// The C MuJoCo backend's physics step as a compiled XLA FFI handler (CPU).
//
// It does what grounding_jax.sim.physics._MujocoRunner.step does through mujoco.rollout, for
// every live row of a batch: set the state (time 0, qpos, qvel), zero the warm start, set the
// control, take `substeps` mj_step (stopping early, as mujoco.rollout does, once MuJoCo has
// raised a warning), and return qpos, qvel and the sensor data of the last substep (float32).
// Finished rows come back unchanged with zero sensor data. Rows run on a persistent pool of
// threads, one MjData each; the calling thread takes rows too.
//
// It needs neither MuJoCo's nor XLA's headers: MuJoCo's functions and each MjData's buffers
// come from Python as addresses (gj_setup), and the few structs of XLA's FFI C API
// (xla/ffi/api/c_api.h, version 0.1) that it reads are declared below, as the ctypes
// fallback (grounding_jax/sim/_ffi.py) declares them.

#include <Python.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <new>
#include <string>
#include <thread>
#include <vector>

#ifndef _WIN32
#include <pthread.h>
#endif

namespace {

// ------------------------------------------------------------------ XLA FFI C API (subset)
struct ExtBase {
  size_t struct_size;
  int type;
  ExtBase* next;
};
struct Buffer {
  size_t struct_size;
  void* ext;
  int dtype;
  void* data;
  int64_t rank;
  int64_t* dims;
};
struct List {
  size_t struct_size;
  void* ext;
  int64_t size;
  int* types;
  void** items;
};
struct ByteSpan {
  const char* ptr;
  size_t len;
};
struct Scalar {
  int dtype;
  void* value;
};
struct Attrs {
  size_t struct_size;
  void* ext;
  int64_t size;
  int* types;
  ByteSpan** names;
  void** items;
};
struct CallFrame {
  size_t struct_size;
  ExtBase* ext;
  void* api;
  void* ctx;
  int stage;
  List args;
  List rets;
  Attrs attrs;
};
struct ApiVersion {
  size_t struct_size;
  void* ext;
  int major;
  int minor;
};
struct Metadata {
  size_t struct_size;
  ApiVersion api_version;
  uint32_t traits;
};
struct MetadataExtension {
  ExtBase base;
  Metadata* metadata;
};
struct ErrorCreateArgs {
  size_t struct_size;
  void* ext;
  const char* message;
  int errc;
};
typedef void* (*ErrorCreate)(ErrorCreateArgs*);
struct Api {
  size_t struct_size;
  void* ext;
  ApiVersion api_version;
  void* internal_api;
  ErrorCreate error_create;
};

constexpr int kExecute = 3;      // XLA_FFI_ExecutionStage_EXECUTE
constexpr int kMetadata = 1;     // XLA_FFI_Extension_Metadata
constexpr int kScalarAttr = 3;   // XLA_FFI_AttrType_SCALAR
constexpr int kF32 = 11;         // XLA_FFI_DataType_F32
constexpr int kS32 = 4;          // XLA_FFI_DataType_S32
constexpr int kInternal = 13;    // XLA_FFI_Error_Code_INTERNAL

void* Error(CallFrame* frame, const std::string& message) {
  Api* api = static_cast<Api*>(frame->api);
  ErrorCreateArgs args;
  args.struct_size = offsetof(ErrorCreateArgs, errc) + sizeof(int);
  args.ext = nullptr;
  args.message = message.c_str();
  args.errc = kInternal;
  return api->error_create(&args);
}

// ------------------------------------------------------------------------------- the engine
typedef void (*StepFn)(const void* m, void* d);
typedef void (*SetStateFn)(const void* m, void* d, const double* state, unsigned int spec);
typedef void (*GetStateFn)(const void* m, const void* d, double* state, unsigned int spec);

struct Worker {
  void* data = nullptr;
  const double* sensordata = nullptr;
  int32_t* warnings = nullptr;  // mjData.warning[i].number, `warning_stride` ints apart
  std::vector<double> state, ctrl, zeros;
};

struct Engine {
  bool ready = false;
  const void* model = nullptr;
  int nq = 0, nv = 0, nu = 0, nsens = 0, nwarning = 0, warning_stride = 0;
  unsigned int spec_full = 0, spec_ctrl = 0, spec_warm = 0;
  StepFn step = nullptr;
  SetStateFn set_state = nullptr;
  GetStateFn get_state = nullptr;
  std::vector<Worker> workers;
  // the pool
  std::vector<std::thread> threads;
  std::mutex mu;
  std::condition_variable wake, finished;
  uint64_t generation = 0;
  int busy = 0;
  bool stop = false;
  std::mutex call_mu;  // one batch at a time (the MjData are not shared between batches)
  // the batch in flight
  const float* in = nullptr;
  float* out = nullptr;
  int64_t rows = 0;
  int substeps = 0;
  std::atomic<int64_t> next{0};
  // counters and a sample of the simulated rows (every 16th call), read by PhysicsMeter
  std::atomic<int64_t> calls{0}, seconds_ns{0};
  std::vector<int64_t> rl_steps;  // by substeps (index 0: more than the table holds)
  int keep = 0;
  int64_t seen = 0, filled = 0;
  uint64_t rng = 0x9E3779B97F4A7C15ull;
  std::vector<double> sample_state, sample_ctrl;
  std::vector<int32_t> sample_substeps;
};

Engine E;

inline int InWidth() { return E.nq + E.nv + E.nu + 1; }
inline int OutWidth() { return E.nq + E.nv + E.nsens; }

void SimulateRow(Worker& w, int64_t r) {
  const float* x = E.in + r * InWidth();
  float* y = E.out + r * OutWidth();
  const int nqv = E.nq + E.nv;
  if (!(x[nqv + E.nu] > 0.5f)) {  // a finished episode: no physics
    for (int i = 0; i < nqv; i++) y[i] = x[i];
    for (int i = 0; i < E.nsens; i++) y[nqv + i] = 0.0f;
    return;
  }
  w.state[0] = 0.0;
  for (int i = 0; i < nqv; i++) w.state[1 + i] = static_cast<double>(x[i]);
  for (int i = 0; i < E.nu; i++) w.ctrl[i] = static_cast<double>(x[nqv + i]);
  E.set_state(E.model, w.data, w.state.data(), E.spec_full);
  E.set_state(E.model, w.data, w.zeros.data(), E.spec_warm);
  E.set_state(E.model, w.data, w.ctrl.data(), E.spec_ctrl);
  for (int i = 0; i < E.nwarning; i++) w.warnings[i * E.warning_stride] = 0;
  for (int t = 0; t < E.substeps; t++) {
    bool warned = false;  // as mujoco.rollout: once MuJoCo warns, the state is kept
    for (int i = 0; i < E.nwarning; i++) warned |= w.warnings[i * E.warning_stride] != 0;
    if (warned) break;
    E.step(E.model, w.data);
  }
  E.get_state(E.model, w.data, w.state.data(), E.spec_full);
  for (int i = 0; i < nqv; i++) y[i] = static_cast<float>(w.state[1 + i]);
  for (int i = 0; i < E.nsens; i++) y[nqv + i] = static_cast<float>(w.sensordata[i]);
}

void Drain(Worker& w) {
  for (int64_t r = E.next.fetch_add(1); r < E.rows; r = E.next.fetch_add(1)) {
    SimulateRow(w, r);
  }
}

void Loop(int id) {
  uint64_t seen_generation = 0;
  for (;;) {
    {
      std::unique_lock<std::mutex> lock(E.mu);
      E.wake.wait(lock, [&] { return E.stop || E.generation != seen_generation; });
      if (E.stop) return;
      seen_generation = E.generation;
    }
    Drain(E.workers[id]);
    {
      std::lock_guard<std::mutex> lock(E.mu);
      if (--E.busy == 0) E.finished.notify_one();
    }
  }
}

uint64_t NextRandom() {  // xorshift64*: the sample's own stream, no run's keys
  E.rng ^= E.rng >> 12;
  E.rng ^= E.rng << 25;
  E.rng ^= E.rng >> 27;
  return E.rng * 0x2545F4914F6CDD1Dull;
}

void Count() {
  int64_t live = 0;
  const int w = InWidth();
  for (int64_t r = 0; r < E.rows; r++) live += E.in[r * w + w - 1] > 0.5f;
  const size_t slot = E.substeps < static_cast<int>(E.rl_steps.size()) ? E.substeps : 0;
  E.rl_steps[slot] += live;
  int64_t call = E.calls.fetch_add(1) + 1;
  if (call % 16 || E.keep == 0) return;
  const int nqv = E.nq + E.nv;
  for (int64_t r = 0; r < E.rows; r++) {
    const float* x = E.in + r * w;
    if (!(x[w - 1] > 0.5f)) continue;
    E.seen++;
    int64_t i;
    if (E.filled < E.keep) {
      i = E.filled++;
    } else {
      i = static_cast<int64_t>(NextRandom() % static_cast<uint64_t>(E.seen));
      if (i >= E.keep) continue;
    }
    double* s = &E.sample_state[i * (1 + nqv)];
    s[0] = 0.0;
    for (int k = 0; k < nqv; k++) s[1 + k] = x[k];
    for (int k = 0; k < E.nu; k++) E.sample_ctrl[i * E.nu + k] = x[nqv + k];
    E.sample_substeps[i] = E.substeps;
  }
}

void Run(const float* in, float* out, int64_t rows, int substeps, bool count);

void* Handler(CallFrame* frame) {
  if (frame->ext && frame->ext->type == kMetadata) {
    Metadata* meta = reinterpret_cast<MetadataExtension*>(frame->ext)->metadata;
    meta->api_version.struct_size = offsetof(ApiVersion, minor) + sizeof(int);
    meta->api_version.major = 0;
    meta->api_version.minor = 1;
    meta->traits = 0;
    return nullptr;
  }
  if (frame->stage != kExecute) return nullptr;
  if (!E.ready) return Error(frame, "grounding_jax: the compiled physics step is not set up");
  if (frame->args.size != 1 || frame->rets.size != 1) {
    return Error(frame, "grounding_jax physics step: expected one input and one output");
  }
  Buffer* in = static_cast<Buffer*>(frame->args.items[0]);
  Buffer* out = static_cast<Buffer*>(frame->rets.items[0]);
  if (in->dtype != kF32 || out->dtype != kF32 || in->rank < 1 || out->rank != in->rank) {
    return Error(frame, "grounding_jax physics step: expected float32 arrays of equal rank");
  }
  int64_t rows = 1;
  for (int64_t i = 0; i + 1 < in->rank; i++) {
    rows *= in->dims[i];
    if (out->dims[i] != in->dims[i]) {
      return Error(frame, "grounding_jax physics step: input and output batch shapes differ");
    }
  }
  if (in->dims[in->rank - 1] != InWidth() || out->dims[out->rank - 1] != OutWidth()) {
    return Error(frame, "grounding_jax physics step: row widths do not match the scene");
  }
  int substeps = -1;
  for (int64_t i = 0; i < frame->attrs.size; i++) {
    ByteSpan* name = frame->attrs.names[i];
    if (std::string(name->ptr, name->len) != "substeps") continue;
    Scalar* s = static_cast<Scalar*>(frame->attrs.items[i]);
    if (frame->attrs.types[i] != kScalarAttr || s->dtype != kS32) {
      return Error(frame, "grounding_jax physics step: substeps must be an int32 scalar");
    }
    substeps = *static_cast<int32_t*>(s->value);
  }
  if (substeps < 0) return Error(frame, "grounding_jax physics step: no substeps attribute");
  Run(static_cast<const float*>(in->data), static_cast<float*>(out->data), rows, substeps,
      true);
  return nullptr;
}

void Run(const float* in, float* out, int64_t rows, int substeps, bool count) {
  std::lock_guard<std::mutex> call(E.call_mu);
  auto t0 = std::chrono::steady_clock::now();
  E.in = in;
  E.out = out;
  E.rows = rows;
  E.substeps = substeps;
  if (count) Count();
  E.next.store(0);
  const int helpers = static_cast<int>(E.threads.size());
  if (helpers > 0 && rows > 1) {
    {
      std::lock_guard<std::mutex> lock(E.mu);
      E.busy = helpers;
      E.generation++;
    }
    E.wake.notify_all();
    Drain(E.workers[0]);
    std::unique_lock<std::mutex> lock(E.mu);
    E.finished.wait(lock, [] { return E.busy == 0; });
  } else {
    Drain(E.workers[0]);
  }
  if (count) {
    E.seconds_ns += std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::steady_clock::now() - t0).count();
  }
}

void StopPool() {
  {
    std::lock_guard<std::mutex> lock(E.mu);
    E.stop = true;
  }
  E.wake.notify_all();
  for (auto& t : E.threads) t.join();
  E.threads.clear();
  E.stop = false;
}

#ifndef _WIN32
// In a child process made by fork() the pool's threads do not exist, and a lock another
// thread held at the fork stays held: start the child with fresh locks and no helper threads
// (batches then run on the calling thread alone). The old objects are left as they are,
// never joined or destroyed.
void AfterFork() {
  new (&E.mu) std::mutex();
  new (&E.call_mu) std::mutex();
  new (&E.wake) std::condition_variable();
  new (&E.finished) std::condition_variable();
  new (&E.threads) std::vector<std::thread>();
  E.busy = 0;
}
#endif

}  // namespace

extern "C" {

// The FFI handler's address (jax.ffi.pycapsule wraps it).
void* gj_step_handler() { return reinterpret_cast<void*>(&Handler); }

// Sizes: nq, nv, nu, nsensordata, nwarning, warning_stride (ints between two warnings'
// counters), state specs (full physics, control, warm start), sample rows kept. Functions:
// mj_step, mj_setState, mj_getState. Per worker: the MjData, its sensordata and its first
// warning counter. Returns 0, or -1 if a batch is in flight (it is then left as it was).
int gj_setup(const void* model, const int* sizes, const unsigned int* specs, int keep,
             void* step, void* set_state, void* get_state, int nworker, void* const* datas,
             const double* const* sensordata, int32_t* const* warnings) {
  std::unique_lock<std::mutex> call(E.call_mu, std::try_to_lock);
  if (!call.owns_lock()) return -1;
  StopPool();
  E.ready = false;
  E.model = model;
  E.nq = sizes[0];
  E.nv = sizes[1];
  E.nu = sizes[2];
  E.nsens = sizes[3];
  E.nwarning = sizes[4];
  E.warning_stride = sizes[5];
  E.spec_full = specs[0];
  E.spec_ctrl = specs[1];
  E.spec_warm = specs[2];
  E.step = reinterpret_cast<StepFn>(step);
  E.set_state = reinterpret_cast<SetStateFn>(set_state);
  E.get_state = reinterpret_cast<GetStateFn>(get_state);
  E.workers.assign(nworker, Worker());
  for (int i = 0; i < nworker; i++) {
    Worker& w = E.workers[i];
    w.data = datas[i];
    w.sensordata = sensordata[i];
    w.warnings = warnings[i];
    w.state.assign(1 + E.nq + E.nv, 0.0);
    w.ctrl.assign(E.nu, 0.0);
    w.zeros.assign(E.nv, 0.0);
  }
  E.rl_steps.assign(64, 0);
  E.calls = 0;
  E.seconds_ns = 0;
  E.keep = keep;
  E.seen = E.filled = 0;
  E.sample_state.assign(static_cast<size_t>(keep) * (1 + E.nq + E.nv), 0.0);
  E.sample_ctrl.assign(static_cast<size_t>(keep) * E.nu, 0.0);
  E.sample_substeps.assign(keep, 0);
  for (int i = 1; i < nworker; i++) E.threads.emplace_back(Loop, i);
#ifndef _WIN32
  static bool fork_handler = false;
  if (!fork_handler) fork_handler = pthread_atfork(nullptr, nullptr, AfterFork) == 0;
#endif
  E.ready = true;
  return 0;
}

// The step alone, outside XLA (rows of the handler's input and output layouts; not counted):
// the physics ceiling of this engine. Returns -1 if it is not set up.
int gj_run(const float* in, float* out, int64_t rows, int substeps) {
  if (!E.ready) return -1;
  Run(in, out, rows, substeps, false);
  return 0;
}

// Zeroes the counters and empties the sample (a benchmark measuring one run).
void gj_reset_meter() {
  std::lock_guard<std::mutex> call(E.call_mu);
  std::fill(E.rl_steps.begin(), E.rl_steps.end(), 0);
  E.calls = 0;
  E.seconds_ns = 0;
  E.seen = E.filled = 0;
}

// Stops the pool's threads (at exit: a process must not end with them waiting).
void gj_shutdown() {
  std::lock_guard<std::mutex> call(E.call_mu);
  E.ready = false;
  StopPool();
}

// Counters: info = [calls, nanoseconds inside the handler, sample rows filled]; rl_steps[64]
// by substeps (index 0: more substeps than that). With non-null buffers, the sample rows.
void gj_meter(int64_t* info, int64_t* rl_steps, double* state, double* ctrl,
              int32_t* substeps) {
  std::lock_guard<std::mutex> call(E.call_mu);
  info[0] = E.calls;
  info[1] = E.seconds_ns;
  info[2] = E.filled;
  for (size_t i = 0; i < E.rl_steps.size() && i < 64; i++) rl_steps[i] = E.rl_steps[i];
  if (state) {
    std::memcpy(state, E.sample_state.data(), E.filled * (1 + E.nq + E.nv) * sizeof(double));
    std::memcpy(ctrl, E.sample_ctrl.data(), E.filled * E.nu * sizeof(double));
    std::memcpy(substeps, E.sample_substeps.data(), E.filled * sizeof(int32_t));
  }
}

}  // extern "C"

static PyModuleDef module = {PyModuleDef_HEAD_INIT, "_mjstep",
                             "The compiled C MuJoCo physics step (an XLA FFI handler).", -1,
                             nullptr};

PyMODINIT_FUNC PyInit__mjstep(void) { return PyModule_Create(&module); }
