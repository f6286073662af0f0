// The masked GRU's loops for routine_gym/_native/_masked_gru.cpp. No include guard, on purpose: the
// module includes this body twice, once for any CPU and once (x86-64 with GCC) compiled for
// AVX2 and FMA, and picks one at run time. It needs <cmath>, <cstddef>, <cstdint> and <cstring>
// included before it, outside the namespace it is included into.
//
// Layouts, all C-contiguous and batch-major, `B` windows, `T` steps, `H` units:
//   gi [B, T, 3H]   the input gates W_ih x_t + b_ih (r, z, n: GRUCell's order)
//   mask [B, T]     the factor of the state after each step
//   weight [3H, H]  W_hh; bias [3H] b_hh
//   hs [B, T+1, H]  h_{-1} = 0, then h_0 ... h_{T-1}
//   rz [B, T, 2H]   σ of the r and z gates; n [B, T, H] the candidate; ghn [B, T, H] W_hn h + b_hn
// A thread runs rows [row0, row1) of the batch through every step: the rows do not interact,
// so what a row computes does not depend on how the batch is split among threads.

// C[M, N] += A[M, K] · B[K, N], rows `lda`, `ldb`, `ldc` apart, in tiles of 4 rows by two vectors
// (eight accumulators in registers); the columns past the last whole tile one at a time.
template <typename T>
struct Lanes;
template <>
struct Lanes<float> {
  typedef float Vec __attribute__((vector_size(32)));
  static constexpr int width = 8;
};
template <>
struct Lanes<double> {
  typedef double Vec __attribute__((vector_size(32)));
  static constexpr int width = 4;
};

template <typename T>
inline typename Lanes<T>::Vec load(const T* p) {
  typename Lanes<T>::Vec v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

template <typename T>
inline void store(T* p, typename Lanes<T>::Vec v) {
  std::memcpy(p, &v, sizeof v);
}

template <typename T, int MR>
inline void gemm_tile(std::ptrdiff_t k_size, const T* a, std::ptrdiff_t lda, const T* b,
                      std::ptrdiff_t ldb, T* c, std::ptrdiff_t ldc) {
  typedef typename Lanes<T>::Vec Vec;
  constexpr int W = Lanes<T>::width;
  Vec acc[MR][2];
  for (int i = 0; i < MR; ++i) {
    acc[i][0] = load<T>(c + i * ldc);
    acc[i][1] = load<T>(c + i * ldc + W);
  }
  for (std::ptrdiff_t k = 0; k < k_size; ++k) {
    const Vec b0 = load<T>(b + k * ldb), b1 = load<T>(b + k * ldb + W);
    for (int i = 0; i < MR; ++i) {
      const T s = a[i * lda + k];  // broadcast to every lane
      acc[i][0] += s * b0;
      acc[i][1] += s * b1;
    }
  }
  for (int i = 0; i < MR; ++i) {
    store<T>(c + i * ldc, acc[i][0]);
    store<T>(c + i * ldc + W, acc[i][1]);
  }
}

template <typename T, int MR>
inline void gemm_rows(std::ptrdiff_t n_size, std::ptrdiff_t k_size, const T* a,
                      std::ptrdiff_t lda, const T* b, std::ptrdiff_t ldb, T* c,
                      std::ptrdiff_t ldc) {
  constexpr std::ptrdiff_t NR = 2 * Lanes<T>::width;
  std::ptrdiff_t j = 0;
  for (; j + NR <= n_size; j += NR) gemm_tile<T, MR>(k_size, a, lda, b + j, ldb, c + j, ldc);
  for (; j < n_size; ++j) {
    for (int i = 0; i < MR; ++i) {
      T sum = c[i * ldc + j];
      for (std::ptrdiff_t k = 0; k < k_size; ++k) sum += a[i * lda + k] * b[k * ldb + j];
      c[i * ldc + j] = sum;
    }
  }
}

template <typename T>
void gemm_acc(std::ptrdiff_t m_size, std::ptrdiff_t n_size, std::ptrdiff_t k_size, const T* a,
              std::ptrdiff_t lda, const T* b, std::ptrdiff_t ldb, T* c, std::ptrdiff_t ldc) {
  std::ptrdiff_t i = 0;
  for (; i + 4 <= m_size; i += 4)
    gemm_rows<T, 4>(n_size, k_size, a + i * lda, lda, b, ldb, c + i * ldc, ldc);
  for (; i < m_size; ++i)
    gemm_rows<T, 1>(n_size, k_size, a + i * lda, lda, b, ldb, c + i * ldc, ldc);
}

// σ and tanh of an array in place. Doubles (the tests' gradient checks) use the C library; floats
// a branch-free Cephes-style exp (range reduction by ln 2 in two parts, a degree-5 polynomial,
// the power of two written into the exponent bits), which the compiler vectorizes, within a few
// units in the last place of the C library's. A NaN stays NaN through all three (as in torch).
inline void exp_inplace(float* x_array, std::ptrdiff_t size) {
  for (std::ptrdiff_t i = 0; i < size; ++i) {
    float x = x_array[i];
    // Comparisons that are false for NaN, so a NaN passes through the clamps.
    x = x > 88.0f ? 88.0f : x;  // e^88 is finite; σ and tanh saturate long before
    x = x < -87.3f ? -87.3f : x;  // keeps 2^n a normal float
    const float finite = x == x ? x : 0.0f;  // the exponent of a NaN: any valid one
    const int n = static_cast<int>(finite * 1.44269504088896341f + 126.5f) - 126;  // round(x/ln 2)
    const float nf = static_cast<float>(n);
    const float r = (x - nf * 0.693359375f) - nf * -2.12194440e-4f;
    float y = 1.9875691500e-4f;
    y = y * r + 1.3981999507e-3f;
    y = y * r + 8.3334519073e-3f;
    y = y * r + 4.1665795894e-2f;
    y = y * r + 1.6666665459e-1f;
    y = y * r + 5.0000001201e-1f;
    y = y * r * r + r + 1.0f;
    const std::int32_t bits = (n + 127) << 23;
    float scale;
    std::memcpy(&scale, &bits, sizeof scale);
    x_array[i] = y * scale;
  }
}

inline void sigmoid_inplace(float* x, float* scratch, std::ptrdiff_t size) {
  for (std::ptrdiff_t i = 0; i < size; ++i) scratch[i] = -x[i];
  exp_inplace(scratch, size);
  for (std::ptrdiff_t i = 0; i < size; ++i) x[i] = 1.0f / (1.0f + scratch[i]);
}

inline void tanh_inplace(float* x, float* scratch, std::ptrdiff_t size) {
  for (std::ptrdiff_t i = 0; i < size; ++i) scratch[i] = 2.0f * std::fabs(x[i]);
  exp_inplace(scratch, size);
  for (std::ptrdiff_t i = 0; i < size; ++i) {
    const float v = x[i], a = std::fabs(v), z = v * v;
    // |x| < 0.625: x + x^3 P(x^2); above: 1 - 2 / (e^{2|x|} + 1), with x's sign.
    const float small = ((((-5.70498872745e-3f * z + 2.06390887954e-2f) * z
                           - 5.37397155531e-2f) * z + 1.33314422036e-1f) * z
                         - 3.33332819422e-1f) * z * v + v;
    const float large = std::copysign(1.0f - 2.0f / (scratch[i] + 1.0f), v);
    x[i] = a < 0.625f ? small : large;  // NaN: `large`, NaN itself
  }
}

inline void sigmoid_inplace(double* x, double*, std::ptrdiff_t size) {
  for (std::ptrdiff_t i = 0; i < size; ++i) x[i] = 1.0 / (1.0 + std::exp(-x[i]));
}

inline void tanh_inplace(double* x, double*, std::ptrdiff_t size) {
  for (std::ptrdiff_t i = 0; i < size; ++i) x[i] = std::tanh(x[i]);
}

// The forward recurrence of rows [row0, row1): fills hs (from step 1 on), rz, n and ghn.
// `weight_t` is W_hh transposed, [H, 3H]; `work` holds (row1 - row0) · 3H + 2H values.
template <typename T>
void forward_rows(std::ptrdiff_t row0, std::ptrdiff_t row1, std::ptrdiff_t steps,
                  std::ptrdiff_t h, const T* gi, const T* mask, const T* weight_t, const T* bias,
                  T* hs, T* rz, T* n, T* ghn, T* work) {
  const std::ptrdiff_t rows = row1 - row0, h3 = 3 * h, h2 = 2 * h;
  T* gh = work;  // [rows, 3H]: W_hh h_{t-1} + b_hh
  T* scratch = work + rows * h3;
  for (std::ptrdiff_t t = 0; t < steps; ++t) {
    for (std::ptrdiff_t i = 0; i < rows; ++i) std::memcpy(gh + i * h3, bias, h3 * sizeof(T));
    gemm_acc<T>(rows, h3, h, hs + row0 * (steps + 1) * h + t * h, (steps + 1) * h, weight_t, h3,
                gh, h3);
    for (std::ptrdiff_t i = 0; i < rows; ++i) {
      const std::ptrdiff_t row = row0 + i;
      const T* g = gi + (row * steps + t) * h3;
      const T* gh_i = gh + i * h3;
      T* rz_t = rz + (row * steps + t) * h2;
      T* n_t = n + (row * steps + t) * h;
      T* ghn_t = ghn + (row * steps + t) * h;
      const T* previous = hs + (row * (steps + 1) + t) * h;
      T* out = hs + (row * (steps + 1) + t + 1) * h;
      const T m = mask[row * steps + t];
      for (std::ptrdiff_t j = 0; j < h2; ++j) rz_t[j] = g[j] + gh_i[j];
      sigmoid_inplace(rz_t, scratch, h2);
      const T* r = rz_t;
      const T* z = rz_t + h;
      for (std::ptrdiff_t j = 0; j < h; ++j) {
        ghn_t[j] = gh_i[h2 + j];
        n_t[j] = g[h2 + j] + r[j] * ghn_t[j];
      }
      tanh_inplace(n_t, scratch, h);
      for (std::ptrdiff_t j = 0; j < h; ++j) out[j] = (n_t[j] + z[j] * (previous[j] - n_t[j])) * m;
    }
  }
}

// The backward recurrence of rows [row0, row1), from the forward's saved values and ∂L/∂h_t
// (`grad_out` [B, T, H]): fills grad_gh [B, T, 3H] (∂L/∂(W_hh h_{t-1} + b_hh)), grad_gi
// [B, T, 3H] (∂L/∂gi) and grad_mask [B, T]. `weight` is W_hh, [3H, H]; `work` holds
// (row1 - row0) · H values.
template <typename T>
void backward_rows(std::ptrdiff_t row0, std::ptrdiff_t row1, std::ptrdiff_t steps,
                   std::ptrdiff_t h, const T* grad_out, const T* mask, const T* weight,
                   const T* hs, const T* rz, const T* n, const T* ghn, T* grad_gh, T* grad_gi,
                   T* grad_mask, T* work) {
  const std::ptrdiff_t rows = row1 - row0, h3 = 3 * h, h2 = 2 * h;
  T* carried = work;  // [rows, H]: ∂L/∂h_t through the steps after t
  std::memset(carried, 0, rows * h * sizeof(T));
  for (std::ptrdiff_t t = steps - 1; t >= 0; --t) {
    for (std::ptrdiff_t i = 0; i < rows; ++i) {
      const std::ptrdiff_t row = row0 + i, at = row * steps + t;
      const T* go = grad_out + at * h;
      const T* r = rz + at * h2;
      const T* z = r + h;
      const T* n_t = n + at * h;
      const T* ghn_t = ghn + at * h;
      const T* previous = hs + (row * (steps + 1) + t) * h;
      T* gg = grad_gh + at * h3;
      T* gi = grad_gi + at * h3;
      T* c = carried + i * h;
      const T m = mask[at];
      // ∂L/∂m_t first, in its own loop: a sum in order, which would keep the loop below (each
      // element on its own) from being vectorized.
      T grad_m = 0;
      for (std::ptrdiff_t j = 0; j < h; ++j)
        grad_m += (go[j] + c[j]) * (n_t[j] + z[j] * (previous[j] - n_t[j]));
      for (std::ptrdiff_t j = 0; j < h; ++j) {
        const T grad_h = go[j] + c[j];
        const T difference = previous[j] - n_t[j];
        const T grad_n = grad_h * (1 - z[j]) * (1 - n_t[j] * n_t[j]) * m;
        const T grad_r = grad_n * ghn_t[j] * r[j] * (1 - r[j]);
        const T grad_z = grad_h * difference * z[j] * (1 - z[j]) * m;
        gg[j] = grad_r;
        gg[h + j] = grad_z;
        gg[h2 + j] = grad_n * r[j];
        gi[j] = grad_r;
        gi[h + j] = grad_z;
        gi[h2 + j] = grad_n;
        c[j] = grad_h * z[j] * m;  // the path outside the gates; the gates' is added below
      }
      grad_mask[at] = grad_m;
    }
    gemm_acc<T>(rows, h, h3, grad_gh + (row0 * steps + t) * h3, steps * h3, weight, h, carried, h);
  }
}
