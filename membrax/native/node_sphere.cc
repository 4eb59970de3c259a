// Node–sphere contacts of the membrane: forces, torques and the tangential springs, one pass per slot.
//
// An XLA FFI handler for the CPU, compiled on first use by membrax/native.py; the law is that of
// membrax/membrane_contact.py (node_sphere_forces), which remains the reference and supplies the
// derivatives. For each slot (node n, candidate k) with sphere i = idx[n, k] < N:
//   b = x_n − x_i, δ = R_i + t_m/2 − |b|, n̂ = b/|b|, F_n = k_n max(δ, 0) n̂ (on the node),
//   v_t = Π_t[v_n − (v_i + ω_i × b)],
//   s' = Coulomb-capped (|s| Π_t(s)/max(|Π_t(s)|, |s|/2) − k_t v_t Δt), |s'| ≤ μ k_n δ, s' = 0 when δ ≤ 0,
//   F = F_n + s' on the node, −F on the sphere, torque b × (−F) on the sphere.
// A vectorised pass finds the touching slots (about one in ten at paper size); the law and the sums run
// over those alone, in slot order.
//
// Inputs (T: float or double): node_position, node_velocity (n, 3); sphere_position, sphere_velocity,
// sphere_angular_velocity (N, 3); sphere_radius (N,); idx (n, K) i32 padded with N; spring (3, n, K);
// scalars (5,) = Δt, k_n, k_t, μ, t_m.
// Outputs: node_force (n, 3), sphere_force (N, 3), sphere_torque (N, 3), spring' (3, n, K).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "contact_law.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

using membrax::cross;
using membrax::dot;
using membrax::Vec3;

// Pass 1, vectorised: which slots touch, δ = R_i + t_m/2 − |b| > 0 (or is NaN, which the law then
// carries to the outputs as the JAX law does). Other slots give zero force and a zero spring.
template <typename T>
void touching_slots(const T* __restrict node_x, const T* __restrict sphere_x, const T* __restrict radius,
                    const int32_t* __restrict idx, int64_t num_nodes, int64_t capacity, int64_t num_spheres,
                    T half_thickness, uint8_t* __restrict touching) {
  // Slot k of every node, then k + 1: the inner loop runs over nodes and vectorises.
  for (int64_t k = 0; k < capacity; ++k) {
#pragma omp simd
    for (int64_t node = 0; node < num_nodes; ++node) {
      const int64_t j = node * capacity + k;
      const int32_t raw = idx[j];
      const bool valid = raw < num_spheres;
      const int64_t sphere = valid ? raw : 0;
      T distance_sq = T(0);
      for (int c = 0; c < 3; ++c) {
        const T b = node_x[3 * node + c] - sphere_x[3 * sphere + c];
        distance_sq += b * b;
      }
      const T overlap = radius[sphere] + half_thickness - std::sqrt(distance_sq);
      touching[j] = valid & !(overlap <= T(0));
    }
  }
}

// Pass 2: the law of one touching slot (branch b, relative velocity, carried spring s, overlap δ > 0);
// writes the new spring and returns the force on the node.
template <typename T>
inline Vec3<T> slot_law(Vec3<T> b, Vec3<T> relative, Vec3<T> s, T overlap, T dt, T normal_stiffness,
                        T tangential_stiffness, T friction, Vec3<T>* new_spring) {
  const T distance_sq = dot(b, b);
  const bool apart = distance_sq > T(0);
  const Vec3<T> normal = (apart ? T(1) / std::sqrt(distance_sq) : T(0)) * b;
  // F_n = −∂U/∂b = k_n δ n̂ (zero at |b| = 0, where the guarded norm has a zero gradient)
  const T normal_force = apart ? normal_stiffness * overlap : T(0);
  const Vec3<T> tangential_velocity = relative - dot(relative, normal) * normal;
  *new_spring = membrax::tangential_spring(s, normal, tangential_velocity, tangential_stiffness * dt,
                                           friction * normal_force, true);
  return normal_force * normal + *new_spring;
}

template <ffi::DataType dtype>
ffi::Error node_sphere_forces(ffi::Buffer<dtype> node_position, ffi::Buffer<dtype> node_velocity,
                              ffi::Buffer<dtype> sphere_position, ffi::Buffer<dtype> sphere_velocity,
                              ffi::Buffer<dtype> sphere_angular_velocity, ffi::Buffer<dtype> sphere_radius,
                              ffi::Buffer<ffi::S32> idx, ffi::Buffer<dtype> spring, ffi::Buffer<dtype> scalars,
                              ffi::ResultBuffer<dtype> node_force, ffi::ResultBuffer<dtype> sphere_force,
                              ffi::ResultBuffer<dtype> sphere_torque, ffi::ResultBuffer<dtype> new_spring) {
  using T = ffi::NativeType<dtype>;
  const int64_t num_nodes = node_position.element_count() / 3;
  const int64_t num_spheres = sphere_radius.element_count();
  const auto dims = idx.dimensions();
  if (dims.size() != 2 || dims[0] != num_nodes || scalars.element_count() != 5 ||
      spring.element_count() != size_t(3 * num_nodes * dims[1]) ||
      sphere_position.element_count() != size_t(3 * num_spheres)) {
    return ffi::Error::InvalidArgument("node_sphere_forces: inconsistent array sizes");
  }
  const int64_t capacity = dims[1];
  const int64_t m = num_nodes * capacity;
  const T* scalar = scalars.typed_data();
  const T dt = scalar[0], normal_stiffness = scalar[1], tangential_stiffness = scalar[2],
          friction = scalar[3], half_thickness = T(0.5) * scalar[4];
  const T* x = node_position.typed_data();
  const T* v = node_velocity.typed_data();
  const T* xs = sphere_position.typed_data();
  const T* vs = sphere_velocity.typed_data();
  const T* ws = sphere_angular_velocity.typed_data();
  const T* radius = sphere_radius.typed_data();
  const int32_t* id = idx.typed_data();
  const T* old_spring = spring.typed_data();
  T* springs = new_spring->typed_data();
  T* on_node = node_force->typed_data();
  T* on_sphere = sphere_force->typed_data();
  T* torque = sphere_torque->typed_data();
  std::fill(springs, springs + 3 * m, T(0));
  std::fill(on_node, on_node + 3 * num_nodes, T(0));
  std::fill(on_sphere, on_sphere + 3 * num_spheres, T(0));
  std::fill(torque, torque + 3 * num_spheres, T(0));

  thread_local std::vector<uint8_t> touching;
  touching.resize(size_t(m));
  touching_slots<T>(x, xs, radius, id, num_nodes, capacity, num_spheres, half_thickness, touching.data());
  // In slot order, so that each node's force is summed in the order of the JAX law.
  for (int64_t j = 0; j < m; ++j) {
    if (!touching[j]) continue;
    const int64_t node = j / capacity, sphere = id[j];
    const Vec3<T> b = {x[3 * node] - xs[3 * sphere], x[3 * node + 1] - xs[3 * sphere + 1],
                       x[3 * node + 2] - xs[3 * sphere + 2]};
    const Vec3<T> s = {old_spring[j], old_spring[m + j], old_spring[2 * m + j]};
    const Vec3<T> w = {ws[3 * sphere], ws[3 * sphere + 1], ws[3 * sphere + 2]};
    const Vec3<T> node_velocity = {v[3 * node], v[3 * node + 1], v[3 * node + 2]};
    const Vec3<T> sphere_velocity = {vs[3 * sphere], vs[3 * sphere + 1], vs[3 * sphere + 2]};
    const Vec3<T> relative = node_velocity - (sphere_velocity + cross(w, b));  // v_node − (v_i + ω_i × b)
    const T overlap = radius[sphere] + half_thickness - std::sqrt(dot(b, b));
    Vec3<T> updated;
    const Vec3<T> force =
        slot_law<T>(b, relative, s, overlap, dt, normal_stiffness, tangential_stiffness, friction, &updated);
    const Vec3<T> torque_on_sphere = cross(b, T(-1) * force);
    const T spring_out[3] = {updated.x, updated.y, updated.z};
    const T force_out[3] = {force.x, force.y, force.z};
    const T torque_out[3] = {torque_on_sphere.x, torque_on_sphere.y, torque_on_sphere.z};
    for (int c = 0; c < 3; ++c) {
      springs[c * m + j] = spring_out[c];
      on_node[3 * node + c] += force_out[c];
      on_sphere[3 * sphere + c] -= force_out[c];
      torque[3 * sphere + c] += torque_out[c];
    }
  }
  return ffi::Error::Success();
}

}  // namespace

#define MEMBRAX_NODE_SPHERE_HANDLER(name, dtype)                 \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(name, node_sphere_forces<dtype>, \
                                ffi::Ffi::Bind()                 \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<ffi::S32>>()\
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Arg<ffi::Buffer<dtype>>()   \
                                    .Ret<ffi::Buffer<dtype>>()   \
                                    .Ret<ffi::Buffer<dtype>>()   \
                                    .Ret<ffi::Buffer<dtype>>()   \
                                    .Ret<ffi::Buffer<dtype>>());

MEMBRAX_NODE_SPHERE_HANDLER(MembraxNodeSphereForcesF32, ffi::F32)
MEMBRAX_NODE_SPHERE_HANDLER(MembraxNodeSphereForcesF64, ffi::F64)
