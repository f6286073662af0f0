// Compiled recurrence of CompILE's masked GRU for routine_gym.baselines.compile.masked_gru.
//
// The recognition model runs the GRU over a window once per segment, 33 steps of a 16-row batch
// each. In torch each step is a dozen operations on [16, 128] tensors and their backward a dozen
// more, and launching them cost as much as their arithmetic. Here a call runs every step of the
// forward (or the backward) in C++, the batch's rows split among threads (each row's recurrence
// is independent of the others, so a row's numbers do not depend on the thread count), with
// the matrix products in register tiles and σ/tanh vectorized. The GIL is released meanwhile.
//
// The math and the layouts are in _masked_gru_kernel.h; masked_gru.py documents the function and
// computes W_hh's and b_hh's gradients from what `backward` returns (one matrix product in torch).
// tests/test_masked_gru.py checks both entry points against the torch loop and the GRUCell loop.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <atomic>
#include <cstring>
#include <exception>
#include <initializer_list>
#include <thread>
#include <vector>

#include "_pybuffers.h"

namespace {  // internal linkage: both builds of the kernel stay inside this module

namespace portable {
#include "_masked_gru_kernel.h"
}  // namespace portable

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROUTINE_GYM_AVX2 1
#pragma GCC push_options
#pragma GCC target("avx2,fma")
namespace avx2 {
#include "_masked_gru_kernel.h"
}  // namespace avx2
#pragma GCC pop_options
#endif

using routine_gym::Buffers;

// Set by `select`: run the portable build even where the CPU has AVX2 (the tests compare them).
// Atomic: a call reads it with the GIL released while another thread may `select`.
std::atomic<bool> portable_only{false};

bool use_avx2() {
#ifdef ROUTINE_GYM_AVX2
  static const bool supported = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return supported && !portable_only.load();
#else
  return false;
#endif
}

// Runs `body(row0, row1, work)` on min(threads, rows) contiguous pieces of [0, rows), the first
// on this thread and the others on new ones (all of them here when a thread cannot be started).
// Each piece gets its own scratch of `work_per_row` values a row plus `work_extra`, allocated
// here, before any thread starts, so running out of memory is an exception of this thread.
template <typename T, typename Body>
void split_rows(std::ptrdiff_t rows, int threads, std::ptrdiff_t work_per_row,
                std::ptrdiff_t work_extra, Body body) {
  const int chunks = static_cast<int>(rows < threads ? rows : threads);
  auto bound = [&](int k) { return rows * k / chunks; };
  std::vector<std::vector<T>> work(chunks);
  for (int k = 0; k < chunks; ++k)
    work[k].resize((bound(k + 1) - bound(k)) * work_per_row + work_extra);
  std::vector<std::thread> helpers;
  for (int k = 1; k < chunks; ++k) {
    try {
      helpers.emplace_back(body, bound(k), bound(k + 1), work[k].data());
    } catch (const std::exception&) {
      body(bound(k), bound(k + 1), work[k].data());
    }
  }
  body(bound(0), bound(1), work[0].data());
  for (auto& helper : helpers) helper.join();
}

template <typename T>
void run_forward(std::ptrdiff_t batch, std::ptrdiff_t steps, std::ptrdiff_t h, int threads,
                 const T* gi, const T* mask, const T* weight_t, const T* bias, T* hs, T* rz, T* n,
                 T* ghn) {
  for (std::ptrdiff_t row = 0; row < batch; ++row)
    std::memset(hs + row * (steps + 1) * h, 0, h * sizeof(T));
  const bool fast = use_avx2();
  // forward_rows' scratch: the step's gates, 3H a row, and σ/tanh's 2H.
  split_rows<T>(batch, threads, 3 * h, 2 * h, [&](std::ptrdiff_t row0, std::ptrdiff_t row1,
                                                  T* work) {
#ifdef ROUTINE_GYM_AVX2
    if (fast) {
      avx2::forward_rows<T>(row0, row1, steps, h, gi, mask, weight_t, bias, hs, rz, n, ghn,
                            work);
      return;
    }
#endif
    (void)fast;
    portable::forward_rows<T>(row0, row1, steps, h, gi, mask, weight_t, bias, hs, rz, n, ghn,
                              work);
  });
}

template <typename T>
void run_backward(std::ptrdiff_t batch, std::ptrdiff_t steps, std::ptrdiff_t h, int threads,
                  const T* grad_out, const T* mask, const T* weight, const T* hs, const T* rz,
                  const T* n, const T* ghn, T* grad_gh, T* grad_gi, T* grad_mask) {
  const bool fast = use_avx2();
  // backward_rows' scratch: the gradient carried to the previous step, H a row.
  split_rows<T>(batch, threads, h, 0, [&](std::ptrdiff_t row0, std::ptrdiff_t row1, T* work) {
#ifdef ROUTINE_GYM_AVX2
    if (fast) {
      avx2::backward_rows<T>(row0, row1, steps, h, grad_out, mask, weight, hs, rz, n, ghn,
                             grad_gh, grad_gi, grad_mask, work);
      return;
    }
#endif
    (void)fast;
    portable::backward_rows<T>(row0, row1, steps, h, grad_out, mask, weight, hs, rz, n, ghn,
                               grad_gh, grad_gi, grad_mask, work);
  });
}

// `factors` multiplied, or -1 (with a Python error set) when the product overflows.
Py_ssize_t product(std::initializer_list<Py_ssize_t> factors) {
  Py_ssize_t out = 1;
  for (Py_ssize_t f : factors) {
    if (__builtin_mul_overflow(out, f, &out)) {
      PyErr_SetString(PyExc_OverflowError, "the buffers' sizes overflow");
      return -1;
    }
  }
  return out;
}

// Runs `body` with the GIL released; a C++ exception in it (memory for the work buffers) becomes
// a Python MemoryError or RuntimeError. Returns false with the error set.
template <typename Body>
bool without_gil(Body body) {
  int failed = 0;  // 1: out of memory, 2: another exception
  Py_BEGIN_ALLOW_THREADS
  try {
    body();
  } catch (const std::bad_alloc&) {
    failed = 1;
  } catch (...) {
    failed = 2;
  }
  Py_END_ALLOW_THREADS
  if (failed == 1) PyErr_NoMemory();
  if (failed == 2) PyErr_SetString(PyExc_RuntimeError, "the masked GRU's loops failed");
  return failed == 0;
}

// The sizes' checks shared by both entry points: all >= 1 and every buffer's byte count
// representable (the largest, [B, T+1, 3H] and [3H, H], checked; the others are smaller).
bool check_sizes(Py_ssize_t b, Py_ssize_t t, Py_ssize_t h, int threads, Py_ssize_t item) {
  if (b < 1 || t < 1 || h < 1) {
    PyErr_Format(PyExc_ValueError, "batch, steps and hidden need to be >= 1, got %zd, %zd, %zd",
                 b, t, h);
    return false;
  }
  if (threads < 1) {
    PyErr_Format(PyExc_ValueError, "threads needs to be >= 1, got %d", threads);
    return false;
  }
  return t < PY_SSIZE_T_MAX && product({b, t + 1, 3, h, item}) >= 0 &&
         product({3, h, h, item}) >= 0;
}

// forward(gi, mask, weight_t, bias, hs, rz, n, ghn, batch, steps, hidden, threads, double), where
// weight_t is W_hh transposed, [H, 3H] (the rows of the step's product's right side)
PyObject* forward(PyObject*, PyObject* args) {
  PyObject *gi_o, *mask_o, *weight_o, *bias_o, *hs_o, *rz_o, *n_o, *ghn_o;
  Py_ssize_t b, t, h;
  int threads, is_double;
  if (!PyArg_ParseTuple(args, "OOOOOOOOnnnip", &gi_o, &mask_o, &weight_o, &bias_o, &hs_o, &rz_o,
                        &n_o, &ghn_o, &b, &t, &h, &threads, &is_double))
    return nullptr;
  const Py_ssize_t item = is_double ? sizeof(double) : sizeof(float);
  if (!check_sizes(b, t, h, threads, item)) return nullptr;
  Buffers bufs;
  void* gi = bufs.get(gi_o, b * t * 3 * h * item, false, "gi");
  void* mask = gi ? bufs.get(mask_o, b * t * item, false, "mask") : nullptr;
  void* weight = mask ? bufs.get(weight_o, 3 * h * h * item, false, "weight_t") : nullptr;
  void* bias = weight ? bufs.get(bias_o, 3 * h * item, false, "bias_hh") : nullptr;
  void* hs = bias ? bufs.get(hs_o, b * (t + 1) * h * item, true, "hs") : nullptr;
  void* rz = hs ? bufs.get(rz_o, b * t * 2 * h * item, true, "rz") : nullptr;
  void* n = rz ? bufs.get(n_o, b * t * h * item, true, "n") : nullptr;
  void* ghn = n ? bufs.get(ghn_o, b * t * h * item, true, "ghn") : nullptr;
  if (ghn == nullptr) return nullptr;
  const bool done = without_gil([&] {
    if (is_double)
      run_forward<double>(b, t, h, threads, static_cast<const double*>(gi),
                          static_cast<const double*>(mask), static_cast<const double*>(weight),
                          static_cast<const double*>(bias), static_cast<double*>(hs),
                          static_cast<double*>(rz), static_cast<double*>(n),
                          static_cast<double*>(ghn));
    else
      run_forward<float>(b, t, h, threads, static_cast<const float*>(gi),
                         static_cast<const float*>(mask), static_cast<const float*>(weight),
                         static_cast<const float*>(bias), static_cast<float*>(hs),
                         static_cast<float*>(rz), static_cast<float*>(n),
                         static_cast<float*>(ghn));
  });
  if (!done) return nullptr;
  Py_RETURN_NONE;
}

// backward(grad_out, mask, weight, hs, rz, n, ghn, grad_gh, grad_gi, grad_mask,
//          batch, steps, hidden, threads, double)
PyObject* backward(PyObject*, PyObject* args) {
  PyObject *go_o, *mask_o, *weight_o, *hs_o, *rz_o, *n_o, *ghn_o, *ggh_o, *ggi_o, *gm_o;
  Py_ssize_t b, t, h;
  int threads, is_double;
  if (!PyArg_ParseTuple(args, "OOOOOOOOOOnnnip", &go_o, &mask_o, &weight_o, &hs_o, &rz_o, &n_o,
                        &ghn_o, &ggh_o, &ggi_o, &gm_o, &b, &t, &h, &threads, &is_double))
    return nullptr;
  const Py_ssize_t item = is_double ? sizeof(double) : sizeof(float);
  if (!check_sizes(b, t, h, threads, item)) return nullptr;
  Buffers bufs;
  void* go = bufs.get(go_o, b * t * h * item, false, "grad_out");
  void* mask = go ? bufs.get(mask_o, b * t * item, false, "mask") : nullptr;
  void* weight = mask ? bufs.get(weight_o, 3 * h * h * item, false, "weight_hh") : nullptr;
  void* hs = weight ? bufs.get(hs_o, b * (t + 1) * h * item, false, "hs") : nullptr;
  void* rz = hs ? bufs.get(rz_o, b * t * 2 * h * item, false, "rz") : nullptr;
  void* n = rz ? bufs.get(n_o, b * t * h * item, false, "n") : nullptr;
  void* ghn = n ? bufs.get(ghn_o, b * t * h * item, false, "ghn") : nullptr;
  void* ggh = ghn ? bufs.get(ggh_o, b * t * 3 * h * item, true, "grad_gh") : nullptr;
  void* ggi = ggh ? bufs.get(ggi_o, b * t * 3 * h * item, true, "grad_gi") : nullptr;
  void* gm = ggi ? bufs.get(gm_o, b * t * item, true, "grad_mask") : nullptr;
  if (gm == nullptr) return nullptr;
  const bool done = without_gil([&] {
    if (is_double)
      run_backward<double>(b, t, h, threads, static_cast<const double*>(go),
                           static_cast<const double*>(mask), static_cast<const double*>(weight),
                           static_cast<const double*>(hs), static_cast<const double*>(rz),
                           static_cast<const double*>(n), static_cast<const double*>(ghn),
                           static_cast<double*>(ggh), static_cast<double*>(ggi),
                           static_cast<double*>(gm));
    else
      run_backward<float>(b, t, h, threads, static_cast<const float*>(go),
                          static_cast<const float*>(mask), static_cast<const float*>(weight),
                          static_cast<const float*>(hs), static_cast<const float*>(rz),
                          static_cast<const float*>(n), static_cast<const float*>(ghn),
                          static_cast<float*>(ggh), static_cast<float*>(ggi),
                          static_cast<float*>(gm));
  });
  if (!done) return nullptr;
  Py_RETURN_NONE;
}

PyObject* simd(PyObject*, PyObject*) {
  return PyUnicode_FromString(use_avx2() ? "avx2" : "portable");
}

PyObject* select(PyObject*, PyObject* arg) {
  const char* name = PyUnicode_Check(arg) ? PyUnicode_AsUTF8(arg) : nullptr;
  if (name == nullptr || (std::strcmp(name, "best") != 0 && std::strcmp(name, "portable") != 0)) {
    PyErr_SetString(PyExc_ValueError, "select: expected 'best' or 'portable'");
    return nullptr;
  }
  portable_only.store(std::strcmp(name, "portable") == 0);
  return simd(nullptr, nullptr);
}

PyMethodDef kMethods[] = {
    {"forward", forward, METH_VARARGS,
     "forward(gi, mask, weight_t, bias_hh, hs, rz, n, ghn, batch, steps, hidden, threads, "
     "double): the masked GRU's forward into hs, rz, n, ghn (weight_t: W_hh transposed)"},
    {"backward", backward, METH_VARARGS,
     "backward(grad_out, mask, weight_hh, hs, rz, n, ghn, grad_gh, grad_gi, grad_mask, batch, "
     "steps, hidden, threads, double): its backward into grad_gh, grad_gi, grad_mask"},
    {"simd", simd, METH_NOARGS, "which build of the loops runs: 'avx2' or 'portable'"},
    {"select", select, METH_O,
     "select('best' or 'portable'): the build to run ('best': AVX2 where the CPU has it); "
     "returns simd()"},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef kModule = {
    PyModuleDef_HEAD_INIT, "routine_gym._native._masked_gru",
    "Compiled recurrence of CompILE's masked GRU (routine_gym.baselines.compile.masked_gru).",
    -1, kMethods, nullptr, nullptr, nullptr, nullptr,
};

}  // namespace

PyMODINIT_FUNC PyInit__masked_gru(void) { return PyModule_Create(&kModule); }
