// Membrane nodal forces −∂(W_stretch + f_b W_bend + p V)/∂x in one pass over triangles and hinges.
//
// An XLA FFI handler for the CPU (asynchronous: its loop runs as a task on XLA's thread pool,
// parallel.h), compiled on first use by membrax/native/__init__.py; the formulas are those
// of membrax/membrane/mesh.py, which remains the reference (see membrax.membrane.mesh.nodal_forces).
// A second handler, membrane_forces_backward, is their reverse-mode rule (below). The per-element loops are written branch-free so that the
// compiler vectorises them; each writes its corner forces into a component-first scratch array, and a
// serial loop adds them to the nodes (a scatter cannot be vectorised safely, and is cheap in order).
//
// Inputs (T: float or double):
//   position       (N, 3) T    node positions, m
//   corner_index   (3T,) i32   first corners of all triangles, then second, then third
//   inverse        (T, 2, 2) T the rest frames D_m⁻¹, 1/m
//   area           (T,) T      rest areas A₀, m²
//   hinge_index    (4E,) i32   edge starts a, ends b, opposite vertices c (first triangle), d (second)
//   edge_weight    (E,) T      3|ē|²/Ā of Discrete Shells
//   rest_dihedral  (E,) T      θ̄, rad
//   bottom_ring, top_ring (n,) i32  the end rings, counter-clockwise seen from +z
//   scalars        (6,) T      E_m (Pa), t_m (m), p (Pa), ν, f_b (bending factor), J_m (Gent's lock)
// Attribute: model (0 neo-Hookean, 1 St Venant–Kirchhoff, 2 Gent: STRETCHING_MODELS of defaults.py).
// Output: force (N, 3) T, N.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "contact_law.h"
#include "dual.h"
#include "parallel.h"
#include "ffi_bind.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

using membrax::Dual;

// atan(a) for 0 ≤ a ≤ 1 (Cephes atanf: relative error ≤ 2.1e-7 on [0, 1], checked against std::atan).
inline float atan_unit(float a) {
  const bool big = a > 0.41421356237309505f;  // tan(π/8): reduce with atan a = π/4 + atan((a−1)/(a+1))
  const float offset = big ? 0.78539816339744831f : 0.0f;
  const float x = big ? (a - 1.0f) / (a + 1.0f) : a;
  const float z = x * x;
  return offset +
         ((((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z -
           3.33329491539e-1f) * z * x + x);
}

// atan(a) for 0 ≤ a ≤ 1 (Cephes atan, rational P/Q: relative error ≤ 2.3e-16 on [0, 1]).
inline double atan_unit(double a) {
  const bool big = a > 0.66;
  const double offset = big ? 0.78539816339744830962 : 0.0;
  const double x = big ? (a - 1.0) / (a + 1.0) : a;
  double z = x * x;
  const double p = ((((-8.750608600031904122785e-1 * z - 1.615753718733365076637e1) * z -
                      7.500855792314704667340e1) * z - 1.228866684490136173410e2) * z -
                    6.485021904942025371773e1);
  const double q = (((((z + 2.485846490142306297962e1) * z + 1.650270098316988542046e2) * z +
                      4.328810604912902668951e2) * z + 4.853903996359136964868e2) * z +
                    1.945506571482613964425e2);
  z = x * (z * p / q) + x;
  return offset + (big ? z + 3.061616997868382943065e-17 : z);
}

// atan2(y, x), branch-free so that loops calling it vectorise.
template <typename T>
inline T atan2_branchless(T y, T x) {
  const T ax = std::fabs(x), ay = std::fabs(y);
  const T largest = std::max(ax, ay), smallest = std::min(ax, ay);
  const T ratio = largest > T(0) ? smallest / (largest > T(0) ? largest : T(1)) : T(0);
  T angle = atan_unit(ratio);
  angle = ay > ax ? T(1.57079632679489661923) - angle : angle;
  angle = x < T(0) ? T(3.14159265358979323846) - angle : angle;
  return y < T(0) ? -angle : angle;
}

// The stretching laws, numbered as the model attribute (STRETCHING_MODELS of defaults.py).
constexpr int kNeoHookean = 0, kSaintVenantKirchhoff = 1, kGent = 2;
// GENT_LOCK_FRACTION of defaults.py: past (I₁ − 3)/J_m = f the Gent energy is its quadratic extension.
constexpr double kLockFraction = 0.9;

// Gent's stress over the neo-Hookean one at s = (I₁ − 3)/J_m: φ'(s) = 1/(1 − s) below the lock fraction f,
// 1/(1 − f) + (s − f)/(1 − f)² above (energies.py, _gent_stiffening_integral); generic in T so that the
// backward kernel evaluates it on dual numbers. Branch-free: selects.
template <typename T, typename S>
__attribute__((always_inline)) inline S gent_stiffening(S below, S past) {
  const T slack = T(1) - T(kLockFraction);
  return T(1) / (T(1) - below) + past / (slack * slack);
}

// The neo-Hookean law's terms (energies.py): w = (E_m/6) bracket, bracket = (4 tr² + 8 tr det − 4 det)/det C
// with det C = 1 + 2 tr + 4 det (Gent's s = (I₁ − 3)/J_m is bracket/J_m), and ∂w/∂E₁₁ = (E_m/6)(by_trace +
// by_det E₂₂), ∂w/∂E₁₂ = −(E_m/6) 2 by_det E₁₂. Generic in the value type V so that the backward kernel
// evaluates it on dual numbers, with the forward kernel's arithmetic.
template <typename V>
struct NeoHookeanTerms {
  V bracket, by_trace, by_det;
};

template <typename T, typename V>
__attribute__((always_inline)) inline NeoHookeanTerms<V> neo_hookean_terms(V e11, V e22, V e12, V trace) {
  const V det = e11 * e22 - e12 * e12;
  const V det_c = T(1) + T(2) * trace + T(4) * det;
  const V bracket = (T(4) * trace * trace + T(8) * trace * det - T(4) * det) / det_c;
  const V by_trace = (T(8) * trace + T(8) * det - T(2) * bracket) / det_c;
  const V by_det = (T(8) * trace - T(4) - T(4) * bracket) / det_c;
  return {bracket, by_trace, by_det};
}

// Stretching and cell pressure of each triangle: corner forces, component-first (corner, component, t).
template <typename T, int kLaw>
void triangle_forces(const T* __restrict x, const int32_t* __restrict corner, const T* __restrict inverse,
                     const T* __restrict area, int64_t num_triangles, T modulus, T thickness,
                     T pressure, T poisson, T locking, T* __restrict out) {
  const int64_t n = num_triangles;
  const T shear = modulus / (T(2) * (T(1) + poisson));
  const T lame = modulus * poisson / (T(1) - poisson * poisson);
  const T sixth_pressure = pressure / T(6);
#pragma omp simd
  for (int64_t t = 0; t < n; ++t) {
    const int64_t i1 = 3 * int64_t(corner[t]), i2 = 3 * int64_t(corner[n + t]),
                  i3 = 3 * int64_t(corner[2 * n + t]);
    const T x1[3] = {x[i1], x[i1 + 1], x[i1 + 2]};
    const T x2[3] = {x[i2], x[i2 + 1], x[i2 + 2]};
    const T x3[3] = {x[i3], x[i3 + 1], x[i3 + 2]};
    const T m00 = inverse[4 * t], m01 = inverse[4 * t + 1], m10 = inverse[4 * t + 2],
            m11 = inverse[4 * t + 3];
    T f1[3], f2[3];
    for (int c = 0; c < 3; ++c) {
      const T e1 = x2[c] - x1[c], e2 = x3[c] - x1[c];
      f1[c] = e1 * m00 + e2 * m10;  // F = [e₁ e₂] D_m⁻¹
      f2[c] = e1 * m01 + e2 * m11;
    }
    const T e11 = T(0.5) * (f1[0] * f1[0] + f1[1] * f1[1] + f1[2] * f1[2] - T(1));
    const T e22 = T(0.5) * (f2[0] * f2[0] + f2[1] * f2[1] + f2[2] * f2[2] - T(1));
    const T e12 = T(0.5) * (f1[0] * f2[0] + f1[1] * f2[1] + f1[2] * f2[2]);
    const T trace = e11 + e22;
    T d11, d22, d12;  // ∂w/∂E₁₁, ∂w/∂E₂₂, ∂w/∂E₁₂ of the energy density
    if constexpr (kLaw == kNeoHookean || kLaw == kGent) {
      // Gent's w = (E_m/6) J_m φ((I₁ − 3)/J_m) has the neo-Hookean derivative times φ'.
      const auto [bracket, by_trace, by_det] = neo_hookean_terms<T, T>(e11, e22, e12, trace);
      T k = modulus / T(6);
      if constexpr (kLaw == kGent) {
        const T ratio = bracket / locking;
        const T below = std::min(ratio, T(kLockFraction));
        const T past = std::max(ratio - T(kLockFraction), T(0));
        k *= gent_stiffening<T, T>(below, past);
      }
      d11 = k * (by_trace + by_det * e22);
      d22 = k * (by_trace + by_det * e11);
      d12 = k * (-T(2) * by_det * e12);
    } else {
      // w = μ(E₁₁² + E₂₂² + 2E₁₂²) + (λ*/2) tr².
      d11 = T(2) * shear * e11 + lame * trace;
      d22 = T(2) * shear * e22 + lame * trace;
      d12 = T(4) * shear * e12;
    }
    const T scale = thickness * area[t];
    const T c11 = scale * d11, c22 = scale * d22, c12 = scale * d12;
    T cross23[3], cross31[3], cross12[3];
    cross23[0] = x2[1] * x3[2] - x2[2] * x3[1];
    cross23[1] = x2[2] * x3[0] - x2[0] * x3[2];
    cross23[2] = x2[0] * x3[1] - x2[1] * x3[0];
    cross31[0] = x3[1] * x1[2] - x3[2] * x1[1];
    cross31[1] = x3[2] * x1[0] - x3[0] * x1[2];
    cross31[2] = x3[0] * x1[1] - x3[1] * x1[0];
    cross12[0] = x1[1] * x2[2] - x1[2] * x2[1];
    cross12[1] = x1[2] * x2[0] - x1[0] * x2[2];
    cross12[2] = x1[0] * x2[1] - x1[1] * x2[0];
    for (int c = 0; c < 3; ++c) {
      // dE₁₁ = f₁·df₁, dE₂₂ = f₂·df₂, dE₁₂ = (f₁·df₂ + f₂·df₁)/2; ∂f₁/∂x = (−m₀₀ − m₁₀, m₀₀, m₁₀).
      const T pull1 = c11 * f1[c] + T(0.5) * c12 * f2[c];
      const T pull2 = c22 * f2[c] + T(0.5) * c12 * f1[c];
      const T g2 = m00 * pull1 + m01 * pull2;
      const T g3 = m10 * pull1 + m11 * pull2;
      out[(0 * 3 + c) * n + t] = g2 + g3 - sixth_pressure * cross23[c];  // −(∂W/∂x₁ + p ∂V/∂x₁)
      out[(1 * 3 + c) * n + t] = -g2 - sixth_pressure * cross31[c];
      out[(2 * 3 + c) * n + t] = -g3 - sixth_pressure * cross12[c];
    }
  }
}

// Bending of each hinge: −2 k w (θ − θ̄) ∂θ/∂(a, b, c, d), component-first (vertex, component, e).
template <typename T>
void hinge_forces(const T* __restrict x, const int32_t* __restrict vertex, const T* __restrict weight,
                  const T* __restrict rest, int64_t num_hinges, T stiffness, T* __restrict out) {
  const int64_t n = num_hinges;
#pragma omp simd
  for (int64_t e = 0; e < n; ++e) {
    const int64_t ia = 3 * int64_t(vertex[e]), ib = 3 * int64_t(vertex[n + e]),
                  ic = 3 * int64_t(vertex[2 * n + e]), id = 3 * int64_t(vertex[3 * n + e]);
    T a[3], b[3], c[3], d[3];
    for (int k = 0; k < 3; ++k) {
      a[k] = x[ia + k];
      b[k] = x[ib + k];
      c[k] = x[ic + k];
      d[k] = x[id + k];
    }
    T edge[3], ca[3], db[3];
    for (int k = 0; k < 3; ++k) {
      edge[k] = b[k] - a[k];
      ca[k] = c[k] - a[k];
      db[k] = d[k] - b[k];
    }
    // n₁ = (b − a) × (c − a), n₂ = (a − b) × (d − b) (membrane.py, _dihedral_and_gradient)
    const T n1[3] = {edge[1] * ca[2] - edge[2] * ca[1], edge[2] * ca[0] - edge[0] * ca[2],
                     edge[0] * ca[1] - edge[1] * ca[0]};
    const T n2[3] = {-(edge[1] * db[2] - edge[2] * db[1]), -(edge[2] * db[0] - edge[0] * db[2]),
                     -(edge[0] * db[1] - edge[1] * db[0])};
    const T length_sq = edge[0] * edge[0] + edge[1] * edge[1] + edge[2] * edge[2];
    const T length = std::sqrt(length_sq > T(0) ? length_sq : T(1));
    const T n12[3] = {n1[1] * n2[2] - n1[2] * n2[1], n1[2] * n2[0] - n1[0] * n2[2],
                      n1[0] * n2[1] - n1[1] * n2[0]};
    const T sine = n12[0] * edge[0] + n12[1] * edge[1] + n12[2] * edge[2];
    const T cosine = length * (n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2]);
    const T area1_sq = n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2];
    const T area2_sq = n2[0] * n2[0] + n2[1] * n2[1] + n2[2] * n2[2];
    const bool degenerate = (area1_sq == T(0)) | (area2_sq == T(0)) | (length_sq == T(0));
    const T angle = degenerate ? T(0) : atan2_branchless(sine, cosine);
    const T w1 = degenerate ? T(0) : T(1) / (degenerate ? T(1) : area1_sq);
    const T w2 = degenerate ? T(0) : T(1) / (degenerate ? T(1) : area2_sq);
    // Force = −∂E/∂x = −2 k w (θ − θ̄) ∂θ/∂x.
    const T coefficient = -T(2) * stiffness * weight[e] * (angle - rest[e]);
    T cb_e = T(0), db_e = T(0), ac_e = T(0), ad_e = T(0);
    for (int k = 0; k < 3; ++k) {
      cb_e += (c[k] - b[k]) * edge[k];
      db_e += db[k] * edge[k];
      ac_e += (a[k] - c[k]) * edge[k];
      ad_e += (a[k] - d[k]) * edge[k];
    }
    const T inverse_length = T(1) / length;
    for (int k = 0; k < 3; ++k) {
      const T along1 = w1 * n1[k], along2 = w2 * n2[k];
      out[(0 * 3 + k) * n + e] = -coefficient * inverse_length * (cb_e * along1 + db_e * along2);
      out[(1 * 3 + k) * n + e] = -coefficient * inverse_length * (ac_e * along1 + ad_e * along2);
      out[(2 * 3 + k) * n + e] = -coefficient * length * along1;
      out[(3 * 3 + k) * n + e] = -coefficient * length * along2;
    }
  }
}

// Adds the component-first corner forces to the nodes.
template <typename T>
void add_to_nodes(const T* __restrict per_corner, const int32_t* __restrict index, int64_t num_corners,
                  int64_t num_elements, T* __restrict force) {
  for (int64_t k = 0; k < num_corners; ++k) {
    const int32_t* node = index + k * num_elements;
    const T* fx = per_corner + (3 * k) * num_elements;
    const T* fy = fx + num_elements;
    const T* fz = fy + num_elements;
    for (int64_t e = 0; e < num_elements; ++e) {
      T* f = force + 3 * int64_t(node[e]);
      f[0] += fx[e];
      f[1] += fy[e];
      f[2] += fz[e];
    }
  }
}

// The cap fans: V_cap = (1/6) Σ_k c·(u_k × v_k), c the ring centroid, (u, v) = (x_k, x_k+1) on the top
// (upward) and (x_k+1, x_k) on the bottom; force −p ∂V_cap/∂x (membrane.py, cap_volume).
template <typename T>
void cap_forces(const T* x, const int32_t* ring, int64_t count, bool upward, T pressure, T* force) {
  if (count == 0) return;
  T centre[3] = {0, 0, 0};
  for (int64_t k = 0; k < count; ++k)
    for (int c = 0; c < 3; ++c) centre[c] += x[3 * int64_t(ring[k]) + c];
  for (int c = 0; c < 3; ++c) centre[c] /= T(count);
  T summed_cross[3] = {0, 0, 0};  // Σ u × v = ∂(6 V_cap)/∂c
  const T factor = -pressure / T(6);
  for (int64_t k = 0; k < count; ++k) {
    const int64_t here = ring[k], after = ring[(k + 1) % count];
    const int64_t iu = 3 * (upward ? here : after), iv = 3 * (upward ? after : here);
    const T* u = x + iu;
    const T* v = x + iv;
    summed_cross[0] += u[1] * v[2] - u[2] * v[1];
    summed_cross[1] += u[2] * v[0] - u[0] * v[2];
    summed_cross[2] += u[0] * v[1] - u[1] * v[0];
    // ∂[c·(u × v)]/∂u = v × c, ∂/∂v = c × u
    force[iu + 0] += factor * (v[1] * centre[2] - v[2] * centre[1]);
    force[iu + 1] += factor * (v[2] * centre[0] - v[0] * centre[2]);
    force[iu + 2] += factor * (v[0] * centre[1] - v[1] * centre[0]);
    force[iv + 0] += factor * (centre[1] * u[2] - centre[2] * u[1]);
    force[iv + 1] += factor * (centre[2] * u[0] - centre[0] * u[2]);
    force[iv + 2] += factor * (centre[0] * u[1] - centre[1] * u[0]);
  }
  for (int64_t k = 0; k < count; ++k)
    for (int c = 0; c < 3; ++c) force[3 * int64_t(ring[k]) + c] += factor * summed_cross[c] / T(count);
}

// Whether the mesh arrays agree with each other and with the positions (both handlers' inputs).
template <ffi::DataType dtype>
bool consistent_sizes(const ffi::Buffer<dtype>& position, const ffi::Buffer<ffi::S32>& corner_index,
                      const ffi::Buffer<dtype>& inverse, const ffi::Buffer<dtype>& area,
                      const ffi::Buffer<ffi::S32>& hinge_index, const ffi::Buffer<dtype>& edge_weight,
                      const ffi::Buffer<dtype>& rest_dihedral, const ffi::Buffer<dtype>& scalars) {
  const size_t num_triangles = area.element_count(), num_hinges = edge_weight.element_count();
  return position.element_count() % 3 == 0 && scalars.element_count() == 6 &&
         corner_index.element_count() == 3 * num_triangles && inverse.element_count() == 4 * num_triangles &&
         hinge_index.element_count() == 4 * num_hinges && rest_dihedral.element_count() == num_hinges;
}

template <ffi::DataType dtype>
ffi::Future membrane_forces(ffi::Buffer<dtype> position, ffi::Buffer<ffi::S32> corner_index,
                            ffi::Buffer<dtype> inverse, ffi::Buffer<dtype> area,
                            ffi::Buffer<ffi::S32> hinge_index, ffi::Buffer<dtype> edge_weight,
                            ffi::Buffer<dtype> rest_dihedral, ffi::Buffer<ffi::S32> bottom_ring,
                            ffi::Buffer<ffi::S32> top_ring, ffi::Buffer<dtype> scalars, ffi::ThreadPool pool,
                            int64_t model, ffi::ResultBuffer<dtype> force) {
  using T = ffi::NativeType<dtype>;
  const int64_t num_nodes = position.element_count() / 3;
  const int64_t num_triangles = area.element_count();
  const int64_t num_hinges = edge_weight.element_count();
  if (!consistent_sizes(position, corner_index, inverse, area, hinge_index, edge_weight, rest_dihedral, scalars)) {
    return membrax::failed(ffi::Error::InvalidArgument("membrane_forces: inconsistent array sizes"));
  }
  if (model < kNeoHookean || model > kGent) {
    return membrax::failed(ffi::Error::InvalidArgument("membrane_forces: unknown stretching model"));
  }
  const T* x = position.typed_data();
  const T* s = scalars.typed_data();
  const T modulus = s[0], thickness = s[1], pressure = s[2], poisson = s[3], bending_factor = s[4],
          locking = s[5];
  T* f = force->typed_data();
  const int32_t* corner = corner_index.typed_data();
  const int32_t* hinge = hinge_index.typed_data();
  const T* inverse_data = inverse.typed_data();
  const T* area_data = area.typed_data();
  const T* weight = edge_weight.typed_data();
  const T* dihedral = rest_dihedral.typed_data();
  const int32_t* bottom = bottom_ring.typed_data();
  const int32_t* top = top_ring.typed_data();
  const int64_t bottom_count = bottom_ring.element_count(), top_count = top_ring.element_count();
  return membrax::on_pool(pool, std::max(num_triangles, num_hinges), [=]() {
    std::fill(f, f + 3 * num_nodes, T(0));
    thread_local std::vector<T> scratch;
    scratch.resize(size_t(12 * std::max(num_triangles, num_hinges)));
    const auto triangles = model == kNeoHookean             ? triangle_forces<T, kNeoHookean>
                           : model == kSaintVenantKirchhoff ? triangle_forces<T, kSaintVenantKirchhoff>
                                                            : triangle_forces<T, kGent>;
    triangles(x, corner, inverse_data, area_data, num_triangles, modulus, thickness, pressure, poisson, locking,
              scratch.data());
    add_to_nodes<T>(scratch.data(), corner, 3, num_triangles, f);
    if (bending_factor != T(0)) {  // a zero factor multiplies the whole bending term: nothing to add
      const T stiffness = bending_factor * modulus * thickness * thickness * thickness /
                          (T(12) * (T(1) - poisson * poisson)) / T(6);  // k_b = D/6
      hinge_forces<T>(x, hinge, weight, dihedral, num_hinges, stiffness, scratch.data());
      add_to_nodes<T>(scratch.data(), hinge, 4, num_hinges, f);
    }
    cap_forces<T>(x, bottom, bottom_count, false, pressure, f);
    cap_forces<T>(x, top, top_count, true, pressure, f);
  });
}


// ---- The backward kernel: Jᵀū = J ū (the forces are −∇Φ, J symmetric) and ū·∂F/∂(E_m, t_m, p, ν, f_b).

// atan2 on dual numbers: the value of atan2_branchless, the tangent (x dy − y dx)/(x² + y²).
template <typename T>
inline Dual<T> atan2_branchless(Dual<T> y, Dual<T> x) {
  const T radius_sq = x.v * x.v + y.v * y.v;
  const T tangent = radius_sq > T(0) ? (x.v * y.d - y.v * x.d) / (radius_sq > T(0) ? radius_sq : T(1)) : T(0);
  return {atan2_branchless(y.v, x.v), tangent};
}

// Sums of ū·∂F/∂(scalar) over the elements.
template <typename T>
struct ScalarSums {
  T modulus = 0, thickness = 0, pressure = 0, poisson = 0, bending = 0, locking = 0;  // bending: ∂/∂k_b
};

// Vectors of dual numbers, as named fields (no indexed arrays), so that the element loops vectorise.
template <typename T>
using DualVec = membrax::Vec3<Dual<T>>;

template <typename T>
__attribute__((always_inline)) inline DualVec<T> operator*(T k, DualVec<T> a) {
  return {k * a.x, k * a.y, k * a.z};
}

// A node's position x and its tangent ū (gathered inside the element loops, which GCC vectorises).
template <typename T>
__attribute__((always_inline)) inline DualVec<T> load_node(const T* x, const T* u, int64_t i) {
  return {Dual<T>{x[i], u[i]}, Dual<T>{x[i + 1], u[i + 1]}, Dual<T>{x[i + 2], u[i + 2]}};
}

// Writes the tangent of a corner force, component-first: out[(corner, c) n + element].
template <typename T>
__attribute__((always_inline)) inline void store_tangent(T* __restrict out, int corner, int64_t n, int64_t e,
                                                         DualVec<T> force) {
  out[(3 * corner + 0) * n + e] = force.x.d;
  out[(3 * corner + 1) * n + e] = force.y.d;
  out[(3 * corner + 2) * n + e] = force.z.d;
}

// ū·v for the tangents ū of a (the position's) and the values of v.
template <typename T>
__attribute__((always_inline)) inline T tangent_dot_value(DualVec<T> a, DualVec<T> v) {
  return a.x.d * v.x.v + a.y.d * v.y.v + a.z.d * v.z.v;
}

// One range of triangles' sums, added in order: Σ A₀ (∂w/∂E per unit E):dE (stretch), Σ E_m t_m A₀
// (its ν-derivative):dE (poisson), Σ ū·∂(6V)/∂x (volume), Σ A₀ (its J_m-derivative per unit E):dE
// (locking); dE the strain's tangent along ū.
template <typename T>
struct TriangleSums {
  T stretch = 0, poisson = 0, volume = 0, locking = 0;
};

// The triangles' corner forces on x + ū ε for triangles [begin, end): their tangents (J ū),
// component-first, and the range's sums. The stretching law is a template argument, so that the loop
// evaluates one law's formula. membrane_stiffness = E_m t_m; partial holds 4 per-element sums.
template <typename T, int kLaw>
TriangleSums<T> triangle_tangents(const T* __restrict x, const T* __restrict u, const int32_t* __restrict corner,
                                  const T* __restrict inverse, const T* __restrict area, int64_t num_triangles,
                                  int64_t begin, int64_t end, T membrane_stiffness, T poisson, T pressure,
                                  T locking, T* __restrict out, T* __restrict partial) {
  using D = Dual<T>;
  using membrax::cross;
  using membrax::dot;
  const int64_t n = num_triangles;
  // Per unit E_m: μ/E = 1/2(1 + ν), λ*/E = ν/(1 − ν²), and their ν-derivatives.
  const T shear_unit = T(1) / (T(2) * (T(1) + poisson));
  const T lame_unit = poisson / (T(1) - poisson * poisson);
  const T shear_unit_nu = -T(1) / (T(2) * (T(1) + poisson) * (T(1) + poisson));
  const T lame_unit_nu = (T(1) + poisson * poisson) / ((T(1) - poisson * poisson) * (T(1) - poisson * poisson));
  const T sixth_pressure = pressure / T(6);
  // Per-element partial sums, added up after the loop. (No `omp simd`: it turns the Vec3 temporaries into
  // per-lane arrays in memory, and GCC then gives up; after inlining, plain -O3 vectorises the loop.)
#pragma GCC ivdep
  for (int64_t t = begin; t < end; ++t) {
    const DualVec<T> x1 = load_node(x, u, 3 * int64_t(corner[t]));
    const DualVec<T> x2 = load_node(x, u, 3 * int64_t(corner[n + t]));
    const DualVec<T> x3 = load_node(x, u, 3 * int64_t(corner[2 * n + t]));
    const T m00 = inverse[4 * t], m01 = inverse[4 * t + 1], m10 = inverse[4 * t + 2],
            m11 = inverse[4 * t + 3];
    const DualVec<T> e1 = x2 - x1, e2 = x3 - x1;
    const DualVec<T> f1 = m00 * e1 + m10 * e2;  // F = [e₁ e₂] D_m⁻¹
    const DualVec<T> f2 = m01 * e1 + m11 * e2;
    const D e11 = T(0.5) * (dot(f1, f1) - T(1));
    const D e22 = T(0.5) * (dot(f2, f2) - T(1));
    const D e12 = T(0.5) * dot(f1, f2);
    const D trace = e11 + e22;
    // ∂w/∂E per unit E_m (triangle_forces' formulas), its ν-derivative (St Venant–Kirchhoff only) and its
    // J_m-derivative (Gent only; jm11 etc. its values).
    D u11, u22, u12;
    T nu11 = T(0), nu22 = T(0), nu12 = T(0);
    T jm11 = T(0), jm22 = T(0), jm12 = T(0);
    if constexpr (kLaw == kNeoHookean || kLaw == kGent) {
      const auto [bracket, by_trace, by_det] = neo_hookean_terms<T, D>(e11, e22, e12, trace);
      u11 = (by_trace + by_det * e22) / T(6);
      u22 = (by_trace + by_det * e11) / T(6);
      u12 = (-T(2) * by_det * e12) / T(6);
      if constexpr (kLaw == kGent) {
        // φ'(s), s = (I₁ − 3)/J_m, on dual numbers; ∂φ'/∂J_m = −φ''(s) s/J_m, φ'' = 1/(1 − min(s, f))².
        const D ratio = bracket / locking;
        const bool locked = ratio.v > T(kLockFraction);
        const D below = membrax::select(locked, membrax::constant(T(kLockFraction)), ratio);
        const D past = membrax::select(locked, ratio - T(kLockFraction), membrax::constant(T(0)));
        const D stiffening = gent_stiffening<T, D>(below, past);
        const T curvature = T(1) / ((T(1) - below.v) * (T(1) - below.v));
        const T by_locking = -curvature * ratio.v / locking;
        jm11 = by_locking * u11.v;
        jm22 = by_locking * u22.v;
        jm12 = by_locking * u12.v;
        u11 = stiffening * u11;
        u22 = stiffening * u22;
        u12 = stiffening * u12;
      }
    } else {
      u11 = T(2) * shear_unit * e11 + lame_unit * trace;
      u22 = T(2) * shear_unit * e22 + lame_unit * trace;
      u12 = T(4) * shear_unit * e12;
      nu11 = T(2) * shear_unit_nu * e11.v + lame_unit_nu * trace.v;
      nu22 = T(2) * shear_unit_nu * e22.v + lame_unit_nu * trace.v;
      nu12 = T(4) * shear_unit_nu * e12.v;
    }
    const T scale = membrane_stiffness * area[t];
    const D c11 = scale * u11, c22 = scale * u22, c12 = scale * u12;
    const DualVec<T> cross23 = cross(x2, x3), cross31 = cross(x3, x1), cross12 = cross(x1, x2);
    const DualVec<T> pull1 = c11 * f1 + (T(0.5) * c12) * f2;
    const DualVec<T> pull2 = c22 * f2 + (T(0.5) * c12) * f1;
    const DualVec<T> g2 = m00 * pull1 + m01 * pull2;
    const DualVec<T> g3 = m10 * pull1 + m11 * pull2;
    store_tangent(out, 0, n, t, (g2 + g3) - sixth_pressure * cross23);  // −(∂W/∂x₁ + p ∂V/∂x₁)
    store_tangent(out, 1, n, t, (T(0) * g2 - g2) - sixth_pressure * cross31);
    store_tangent(out, 2, n, t, (T(0) * g3 - g3) - sixth_pressure * cross12);
    // ū·F_stretch = −E t A₀ (∂w/∂E)/E : dE, dE the strain's tangent; ū·F_pressure = −(p/6) Σ ū_k·∂(6V)/∂x_k.
    const T work_unit = u11.v * e11.d + u22.v * e22.d + u12.v * e12.d;
    const T volume_rate =
        tangent_dot_value(x1, cross23) + tangent_dot_value(x2, cross31) + tangent_dot_value(x3, cross12);
    partial[t] = area[t] * work_unit;
    partial[n + t] = scale * (nu11 * e11.d + nu22 * e22.d + nu12 * e12.d);
    partial[2 * n + t] = volume_rate;
    partial[3 * n + t] = area[t] * (jm11 * e11.d + jm22 * e22.d + jm12 * e12.d);
  }
  TriangleSums<T> sums;
  for (int64_t t = begin; t < end; ++t) {
    sums.stretch += partial[t];
    sums.poisson += partial[n + t];
    sums.volume += partial[2 * n + t];
    sums.locking += partial[3 * n + t];
  }
  return sums;
}

// The bending forces of hinges [begin, end) on x + ū ε: tangents (component-first); returns the
// range's ū·∂F/∂k_b, summed in order.
template <typename T>
T hinge_tangents(const T* __restrict x, const T* __restrict u, const int32_t* __restrict vertex,
                 const T* __restrict weight, const T* __restrict rest, int64_t num_hinges, int64_t begin,
                 int64_t end, T stiffness, T* __restrict out, T* __restrict partial) {
  using D = Dual<T>;
  using membrax::cross;
  using membrax::dot;
  const int64_t n = num_hinges;
#pragma GCC ivdep
  for (int64_t e = begin; e < end; ++e) {
    const DualVec<T> a = load_node(x, u, 3 * int64_t(vertex[e]));
    const DualVec<T> b = load_node(x, u, 3 * int64_t(vertex[n + e]));
    const DualVec<T> c = load_node(x, u, 3 * int64_t(vertex[2 * n + e]));
    const DualVec<T> d = load_node(x, u, 3 * int64_t(vertex[3 * n + e]));
    const DualVec<T> edge = b - a, ca = c - a, db = d - b;
    // n₁ = (b − a) × (c − a), n₂ = (a − b) × (d − b) = (d − b) × (b − a) (hinge_forces)
    const DualVec<T> n1 = cross(edge, ca), n2 = cross(db, edge);
    const D length_sq = dot(edge, edge);
    const D length = membrax::sqrt(membrax::select(length_sq.v > T(0), length_sq, membrax::constant(T(1))));
    const D sine = dot(cross(n1, n2), edge);
    const D cosine = length * dot(n1, n2);
    const D area1_sq = dot(n1, n1), area2_sq = dot(n2, n2);
    const bool degenerate = (area1_sq.v == T(0)) | (area2_sq.v == T(0)) | (length_sq.v == T(0));
    const D angle = membrax::select(degenerate, membrax::constant(T(0)), atan2_branchless(sine, cosine));
    const D w1 = membrax::select(degenerate, membrax::constant(T(0)), T(1) / membrax::select(degenerate, membrax::constant(T(1)), area1_sq));
    const D w2 = membrax::select(degenerate, membrax::constant(T(0)), T(1) / membrax::select(degenerate, membrax::constant(T(1)), area2_sq));
    const D coefficient = (-T(2) * stiffness * weight[e]) * (angle - rest[e]);
    const D cb_e = dot(c - b, edge), db_e = dot(db, edge), ac_e = dot(a - c, edge), ad_e = dot(a - d, edge);
    const DualVec<T> along1 = w1 * n1, along2 = w2 * n2;
    const D end_scale = -coefficient / length;  // −c/|e| on the edge's ends, −c|e| on the wings
    const D wing_scale = -coefficient * length;
    store_tangent(out, 0, n, e, end_scale * (cb_e * along1 + db_e * along2));
    store_tangent(out, 1, n, e, end_scale * (ac_e * along1 + ad_e * along2));
    store_tangent(out, 2, n, e, wing_scale * along1);
    store_tangent(out, 3, n, e, wing_scale * along2);
    // ū·F = −2 k_b w (θ − θ̄) dθ, dθ = ∇θ·ū the angle's tangent.
    partial[e] = -T(2) * weight[e] * (angle.v - rest[e]) * angle.d;
  }
  T bending = 0;
  for (int64_t e = begin; e < end; ++e) bending += partial[e];
  return bending;
}

// The cap fans' pressure forces on x + ū ε (cap_forces): tangents added to the nodes, ū·∂F/∂p.
template <typename T>
void cap_tangents(const T* x, const T* u, const int32_t* ring, int64_t count, bool upward, T pressure, T* tangent,
                  ScalarSums<T>* sums) {
  using D = Dual<T>;
  if (count == 0) return;
  D centre[3] = {membrax::constant(T(0)), membrax::constant(T(0)), membrax::constant(T(0))};
  for (int64_t k = 0; k < count; ++k)
    #pragma GCC unroll 3
    for (int c = 0; c < 3; ++c) centre[c] = centre[c] + D{x[3 * int64_t(ring[k]) + c], u[3 * int64_t(ring[k]) + c]};
  #pragma GCC unroll 3
  for (int c = 0; c < 3; ++c) centre[c] = centre[c] / T(count);
  D summed_cross[3] = {membrax::constant(T(0)), membrax::constant(T(0)), membrax::constant(T(0))};
  const T factor = -pressure / T(6);
  T work_unit = 0;  // ū·F per unit p
  for (int64_t k = 0; k < count; ++k) {
    const int64_t here = ring[k], after = ring[(k + 1) % count];
    const int64_t iu = 3 * (upward ? here : after), iv = 3 * (upward ? after : here);
    const D p[3] = {D{x[iu], u[iu]}, D{x[iu + 1], u[iu + 1]}, D{x[iu + 2], u[iu + 2]}};
    const D q[3] = {D{x[iv], u[iv]}, D{x[iv + 1], u[iv + 1]}, D{x[iv + 2], u[iv + 2]}};
    summed_cross[0] = summed_cross[0] + (p[1] * q[2] - p[2] * q[1]);
    summed_cross[1] = summed_cross[1] + (p[2] * q[0] - p[0] * q[2]);
    summed_cross[2] = summed_cross[2] + (p[0] * q[1] - p[1] * q[0]);
    const D on_u[3] = {q[1] * centre[2] - q[2] * centre[1], q[2] * centre[0] - q[0] * centre[2],
                       q[0] * centre[1] - q[1] * centre[0]};
    const D on_v[3] = {centre[1] * p[2] - centre[2] * p[1], centre[2] * p[0] - centre[0] * p[2],
                       centre[0] * p[1] - centre[1] * p[0]};
    #pragma GCC unroll 3
    for (int c = 0; c < 3; ++c) {
      tangent[iu + c] += factor * on_u[c].d;
      tangent[iv + c] += factor * on_v[c].d;
      work_unit += -(u[iu + c] * on_u[c].v + u[iv + c] * on_v[c].v) / T(6);
    }
  }
  for (int64_t k = 0; k < count; ++k)
    #pragma GCC unroll 3
    for (int c = 0; c < 3; ++c) {
      const int64_t i = 3 * int64_t(ring[k]) + c;
      tangent[i] += factor * summed_cross[c].d / T(count);
      work_unit += -u[i] * summed_cross[c].v / (T(6) * T(count));
    }
  sums->pressure += work_unit;
}

// Inputs: those of membrane_forces, then the forces' cotangent ū (N, 3) and an addend a (N, 3).
// Attributes: model, and bending_derivative (1: ū·∂F/∂f_b is wanted, so the hinges run even at f_b = 0).
// Outputs: the position's cotangent a + J ū (N, 3) and the scalars' (6,): ū·∂F/∂(E_m, t_m, p, ν, f_b, J_m).
// The addend is the positions' cotangent from the rest of the step: the caller may alias it to the
// first output (XLA's input_output_aliases), and then J ū is added in place, with no separate sum.
template <ffi::DataType dtype>
ffi::Error membrane_forces_backward(ffi::Buffer<dtype> position, ffi::Buffer<ffi::S32> corner_index,
                                    ffi::Buffer<dtype> inverse, ffi::Buffer<dtype> area,
                                    ffi::Buffer<ffi::S32> hinge_index, ffi::Buffer<dtype> edge_weight,
                                    ffi::Buffer<dtype> rest_dihedral, ffi::Buffer<ffi::S32> bottom_ring,
                                    ffi::Buffer<ffi::S32> top_ring, ffi::Buffer<dtype> scalars,
                                    ffi::Buffer<dtype> cotangent, ffi::Buffer<dtype> addend,
                                    ffi::ThreadPool pool, int64_t model,
                                    int64_t bending_derivative, ffi::ResultBuffer<dtype> position_cotangent,
                                    ffi::ResultBuffer<dtype> scalars_cotangent) {
  using T = ffi::NativeType<dtype>;
  const int64_t num_nodes = position.element_count() / 3;
  const int64_t num_triangles = area.element_count();
  const int64_t num_hinges = edge_weight.element_count();
  if (!consistent_sizes(position, corner_index, inverse, area, hinge_index, edge_weight, rest_dihedral, scalars) ||
      cotangent.element_count() != position.element_count() ||
      addend.element_count() != position.element_count()) {
    return ffi::Error::InvalidArgument("membrane_forces_backward: inconsistent array sizes");
  }
  if (model < kNeoHookean || model > kGent) {
    return ffi::Error::InvalidArgument("membrane_forces_backward: unknown stretching model");
  }
  const T* x = position.typed_data();
  const T* u = cotangent.typed_data();
  const T* s = scalars.typed_data();
  const T modulus = s[0], thickness = s[1], pressure = s[2], poisson = s[3], bending_factor = s[4],
          locking = s[5];
  T* tangent = position_cotangent->typed_data();
  const T* start = addend.typed_data();
  if (start != tangent) std::copy(start, start + 3 * num_nodes, tangent);  // else aliased: add in place
  ScalarSums<T> sums;

  const int64_t most = std::max(num_triangles, num_hinges);
  thread_local std::vector<T> scratch, partial_sums;
  scratch.resize(size_t(12 * most));
  partial_sums.resize(size_t(4 * most));
  T* partial = partial_sums.data();
  // The element loops in two halves on two threads (parallel.h); the sums added in the halves' order.
  const auto triangles = model == kNeoHookean             ? triangle_tangents<T, kNeoHookean>
                         : model == kSaintVenantKirchhoff ? triangle_tangents<T, kSaintVenantKirchhoff>
                                                          : triangle_tangents<T, kGent>;
  T* per_corner = scratch.data();
  TriangleSums<T> halves[2];
  membrax::two_halves(pool, num_triangles, [&](int half, int64_t begin, int64_t end) {
    halves[half] = triangles(x, u, corner_index.typed_data(), inverse.typed_data(), area.typed_data(),
                             num_triangles, begin, end, modulus * thickness, poisson, pressure, locking,
                             per_corner, partial);
  });
  const T stretch = halves[0].stretch + halves[1].stretch;
  sums.modulus = -thickness * stretch;
  sums.thickness = -modulus * stretch;
  sums.poisson = -(halves[0].poisson + halves[1].poisson);
  sums.pressure = -(halves[0].volume + halves[1].volume) / T(6);
  sums.locking = -modulus * thickness * (halves[0].locking + halves[1].locking);
  add_to_nodes<T>(scratch.data(), corner_index.typed_data(), 3, num_triangles, tangent);
  // k_b = f_b E t³/(72(1 − ν²)) (D/6). At f_b = 0 the hinges add nothing but ∂/∂f_b, so they run only
  // when that derivative is asked for (bending_derivative); every other output has the factor f_b.
  const T plate = thickness * thickness * thickness / (T(72) * (T(1) - poisson * poisson));
  const T stiffness = bending_factor * modulus * plate;
  if (bending_factor != T(0) || bending_derivative != 0) {
    T bending[2] = {0, 0};
    membrax::two_halves(pool, num_hinges, [&](int half, int64_t begin, int64_t end) {
      bending[half] = hinge_tangents<T>(x, u, hinge_index.typed_data(), edge_weight.typed_data(),
                                        rest_dihedral.typed_data(), num_hinges, begin, end, stiffness,
                                        per_corner, partial);
    });
    sums.bending = bending[0] + bending[1];
  }
  if (bending_factor != T(0)) add_to_nodes<T>(scratch.data(), hinge_index.typed_data(), 4, num_hinges, tangent);
  cap_tangents<T>(x, u, bottom_ring.typed_data(), bottom_ring.element_count(), false, pressure, tangent, &sums);
  cap_tangents<T>(x, u, top_ring.typed_data(), top_ring.element_count(), true, pressure, tangent, &sums);

  const T one_minus = T(1) - poisson * poisson;
  T* out = scalars_cotangent->typed_data();
  out[0] = sums.modulus + sums.bending * bending_factor * plate;
  out[1] = sums.thickness + sums.bending * bending_factor * modulus * T(3) * thickness * thickness /
                                (T(72) * one_minus);
  out[2] = sums.pressure;
  out[3] = sums.poisson + sums.bending * stiffness * T(2) * poisson / one_minus;
  out[4] = sums.bending * modulus * plate;
  out[5] = sums.locking;
  return ffi::Error::Success();
}

}  // namespace

MEMBRAX_DEFINE_HANDLERS(MembraxMembraneForces, membrane_forces, "model");
MEMBRAX_DEFINE_HANDLERS(MembraxMembraneForcesBackward, membrane_forces_backward, "model", "bending_derivative");
