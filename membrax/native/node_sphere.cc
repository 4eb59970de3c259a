// Node–sphere contacts of the membrane: forces, torques and the tangential springs, one pass per slot.
//
// An XLA FFI handler for the CPU (asynchronous: its loop runs as a task on XLA's thread pool,
// parallel.h), compiled on first use by membrax/native/__init__.py; the law is that of
// membrax/membrane/contact.py (node_sphere_forces), which remains the reference; node_sphere_backward
// (below) is its reverse-mode rule. For each slot (node n, candidate k) with sphere i = idx[n, k] < N:
//   b = x_n − x_i, δ = R_i + t_m/2 − |b|, n̂ = b/|b|, F_n = k_n max(δ, 0) n̂ (on the node),
//   v_t = Π_t[v_n − (v_i + ω_i × b)],
//   s' = Coulomb-capped (|s| Π_t(s)/max(|Π_t(s)|, |s|/2) − k_t v_t Δt), |s'| ≤ μ k_n δ, s' = 0 when δ ≤ 0,
//   F = F_n + s' on the node, −F on the sphere, torque b × (−F) on the sphere.
// One pass in slot order: a padded slot is skipped before any gather, and the law runs on the touching
// slots alone (about one in ten at paper size).
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
#include "parallel.h"
#include "ffi_bind.h"
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
                    const int32_t* __restrict idx, int64_t node_begin, int64_t node_end, int64_t capacity,
                    int64_t num_spheres, T half_thickness, uint8_t* __restrict touching) {
  // Slot k of every node in [node_begin, node_end), then k + 1: the inner loop runs over nodes and
  // vectorises.
  for (int64_t k = 0; k < capacity; ++k) {
#pragma omp simd
    for (int64_t node = node_begin; node < node_end; ++node) {
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

// A slot's branch b = x_n − x_i, the sphere's spin ω_i and the relative velocity v_n − (v_i + ω_i × b),
// gathered by the forward kernel and by the backward's pass 1 alike.
template <typename T>
struct SlotKinematics {
  Vec3<T> branch, spin, relative;
};

template <typename T>
inline SlotKinematics<T> slot_kinematics(const T* x, const T* v, const T* xs, const T* vs, const T* ws,
                                         int64_t node, int64_t sphere) {
  using membrax::row3;
  const Vec3<T> b = row3(x, node) - row3(xs, sphere);
  const Vec3<T> w = row3(ws, sphere);
  return {b, w, row3(v, node) - (row3(vs, sphere) + cross(w, b))};
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

// node_sphere_forces' inputs, which its backward takes too: the sizes (n nodes, N spheres, K candidates,
// m = n K slots), the scalars and the arrays' data; `consistent` says whether the sizes agree (the rest is
// zero where not).
template <typename T>
struct SlotInputs {
  bool consistent;
  int64_t num_nodes, num_spheres, capacity, m;
  T dt, normal_stiffness, tangential_stiffness, friction, half_thickness;
  const T *x, *v, *xs, *vs, *ws, *radius, *old_spring;
  const int32_t* id;
};

template <ffi::DataType dtype>
SlotInputs<ffi::NativeType<dtype>> slot_inputs(
    const ffi::Buffer<dtype>& node_position, const ffi::Buffer<dtype>& node_velocity,
    const ffi::Buffer<dtype>& sphere_position, const ffi::Buffer<dtype>& sphere_velocity,
    const ffi::Buffer<dtype>& sphere_angular_velocity, const ffi::Buffer<dtype>& sphere_radius,
    const ffi::Buffer<ffi::S32>& idx, const ffi::Buffer<dtype>& spring, const ffi::Buffer<dtype>& scalars) {
  using T = ffi::NativeType<dtype>;
  const int64_t num_nodes = node_position.element_count() / 3;
  const int64_t num_spheres = sphere_radius.element_count();
  const auto dims = idx.dimensions();
  if (dims.size() != 2 || dims[0] != num_nodes || scalars.element_count() != 5 ||
      spring.element_count() != size_t(3 * num_nodes * dims[1]) ||
      sphere_position.element_count() != size_t(3 * num_spheres)) {
    return {false};
  }
  const T* scalar = scalars.typed_data();
  return {true, num_nodes, num_spheres, dims[1], num_nodes * dims[1], scalar[0], scalar[1], scalar[2], scalar[3],
          T(0.5) * scalar[4], node_position.typed_data(), node_velocity.typed_data(), sphere_position.typed_data(),
          sphere_velocity.typed_data(), sphere_angular_velocity.typed_data(), sphere_radius.typed_data(),
          spring.typed_data(), idx.typed_data()};
}

template <ffi::DataType dtype>
ffi::Future node_sphere_forces(ffi::Buffer<dtype> node_position, ffi::Buffer<dtype> node_velocity,
                               ffi::Buffer<dtype> sphere_position, ffi::Buffer<dtype> sphere_velocity,
                               ffi::Buffer<dtype> sphere_angular_velocity, ffi::Buffer<dtype> sphere_radius,
                               ffi::Buffer<ffi::S32> idx, ffi::Buffer<dtype> spring, ffi::Buffer<dtype> scalars,
                               ffi::ResultBuffer<dtype> node_force, ffi::ResultBuffer<dtype> sphere_force,
                               ffi::ResultBuffer<dtype> sphere_torque, ffi::ResultBuffer<dtype> new_spring,
                               ffi::ThreadPool pool) {
  using T = ffi::NativeType<dtype>;
  const SlotInputs<T> in = slot_inputs(node_position, node_velocity, sphere_position, sphere_velocity,
                                       sphere_angular_velocity, sphere_radius, idx, spring, scalars);
  if (!in.consistent)
    return membrax::failed(ffi::Error::InvalidArgument("node_sphere_forces: inconsistent array sizes"));
  T* springs = new_spring->typed_data();
  T* on_node = node_force->typed_data();
  T* on_sphere = sphere_force->typed_data();
  T* torque = sphere_torque->typed_data();
  return membrax::on_pool(pool, in.m, [=]() {
    std::fill(on_sphere, on_sphere + 3 * in.num_spheres, T(0));
    std::fill(torque, torque + 3 * in.num_spheres, T(0));
    // One pass in slot order (node by node, then candidate by candidate), so that each node's force and
    // each sphere's sums are added in the order of the JAX law. A padded slot (i = N) is skipped before
    // any gather, and a valid one's law runs only where δ > 0 (or δ is NaN, which the law then carries
    // to the outputs as the JAX law does); every other slot gives zero force and a zero spring.
    // A slot's new spring is written after its old one is read, and no other slot's is read: so the
    // springs may be updated in place (input_output_aliases, node_sphere_kernel).
    const int64_t capacity = in.capacity;
    for (int64_t node = 0; node < in.num_nodes; ++node) {
      Vec3<T> node_sum{T(0), T(0), T(0)};
      for (int64_t j = node * capacity; j < (node + 1) * capacity; ++j) {
        const int32_t sphere = in.id[j];
        bool touching = sphere < in.num_spheres;
        Vec3<T> b{};
        T overlap = T(0);
        if (touching) {
          b = membrax::row3(in.x, node) - membrax::row3(in.xs, sphere);
          overlap = in.radius[sphere] + in.half_thickness - std::sqrt(dot(b, b));
          touching = !(overlap <= T(0));
        }
        if (!touching) {
          springs[j] = springs[in.m + j] = springs[2 * in.m + j] = T(0);
          continue;
        }
        const Vec3<T> relative = slot_kinematics(in.x, in.v, in.xs, in.vs, in.ws, node, sphere).relative;
        const Vec3<T> s = membrax::column3(in.old_spring, 0, in.m, j);
        Vec3<T> updated;
        const Vec3<T> force = slot_law<T>(b, relative, s, overlap, in.dt, in.normal_stiffness,
                                          in.tangential_stiffness, in.friction, &updated);
        const Vec3<T> torque_on_sphere = cross(b, T(-1) * force);
        springs[j] = updated.x;
        springs[in.m + j] = updated.y;
        springs[2 * in.m + j] = updated.z;
        node_sum = node_sum + force;
        membrax::add3(on_sphere, sphere, T(-1) * force);
        membrax::add3(torque, sphere, torque_on_sphere);
      }
      on_node[3 * node] = node_sum.x;
      on_node[3 * node + 1] = node_sum.y;
      on_node[3 * node + 2] = node_sum.z;
    }
  });
}


// ---- The backward kernel: the law of each touching slot run backwards by hand (reverse mode).

template <typename T>
struct SlotCotangents {
  Vec3<T> branch, relative, spring;
  T overlap, dt, normal_stiffness, tangential_stiffness, friction;
  Vec3<T> force;   // the law's value F on the node, for the torque's cotangent
  Vec3<T> normal;  // n̂ = b/|b| (zero at |b| = 0), for the overlap's share of b̄
};

// The cotangents of slot_law's inputs from those of its force on the node (force_bar) and its new spring
// (spring_bar), slot_law run backwards by hand (a touching slot); branch-free, so that its loop vectorises.
template <typename T>
__attribute__((always_inline)) inline SlotCotangents<T> slot_law_backward(
    Vec3<T> b, Vec3<T> relative, Vec3<T> s, T overlap, T dt, T normal_stiffness, T tangential_stiffness,
    T friction, Vec3<T> force_bar, Vec3<T> spring_bar) {
  const T distance_sq = dot(b, b);
  const bool apart = distance_sq > T(0);
  const T distance = std::sqrt(apart ? distance_sq : T(1));
  const T inverse_distance = apart ? T(1) / distance : T(0);
  const Vec3<T> normal = inverse_distance * b;
  const T normal_force = apart ? normal_stiffness * overlap : T(0);
  const T normal_speed = dot(relative, normal);
  const Vec3<T> tangential_velocity = relative - normal_speed * normal;

  // F = F_n n̂ + s', so s' receives F̄ too.
  SlotCotangents<T> bar{};
  T normal_force_bar = dot(force_bar, normal);
  const membrax::SpringCotangents<T> spring = membrax::tangential_spring_backward(
      s, normal, tangential_velocity, tangential_stiffness * dt, friction * normal_force, spring_bar + force_bar);
  Vec3<T> normal_bar = normal_force * force_bar + spring.normal;
  bar.friction = spring.limit * normal_force;
  normal_force_bar += spring.limit * friction;
  bar.tangential_stiffness = spring.stiffness_dt * dt;
  bar.dt = spring.stiffness_dt * tangential_stiffness;
  // v_t = v − (v·n̂) n̂
  const T normal_speed_bar = -dot(spring.tangential_velocity, normal);
  normal_bar = normal_bar - normal_speed * spring.tangential_velocity + normal_speed_bar * relative;
  bar.relative = spring.tangential_velocity + normal_speed_bar * normal;
  // F_n = k_n δ, n̂ = b/|b| (both zero at |b| = 0)
  bar.normal_stiffness = apart ? normal_force_bar * overlap : T(0);
  bar.overlap = apart ? normal_force_bar * normal_stiffness : T(0);
  bar.branch = inverse_distance * (normal_bar - dot(normal_bar, normal) * normal);
  bar.spring = spring.spring;
  bar.force = normal_force * normal + spring.new_spring;
  bar.normal = normal;
  return bar;
}

// The backward's rows per touching slot (component-first, one entry per touching slot): what pass 1
// gathers, and what pass 2 computes for pass 3's sums.
enum SlotGathered { kBranchIn = 0, kRelativeIn = 3, kSpringIn = 6, kAngularIn = 9, kForceBarIn = 12,
                    kTorqueBarIn = 15, kSpringBarIn = 18, kOverlapIn = 21, kGathered };
enum SlotShare { kBranch = 0, kRelative = 3, kAngular = 6, kSpring = 9, kOverlap = 12, kDt, kNormalStiffness,
                 kTangentialStiffness, kFriction, kShares };

// Pass 2, vectorised: the law of each touching slot in [begin, end) run backwards, from the gathered rows
// to the shares.
// (Not inlined: inlined into the handler, GCC 12 leaves the loop scalar.)
template <typename T>
__attribute__((noinline)) void slot_laws_backward(const T* __restrict in, int64_t count, int64_t begin, int64_t end,
                                                  T dt, T normal_stiffness, T tangential_stiffness, T friction,
                                                  T* __restrict share) {
  auto row = [count, in](int q, int64_t t) { return membrax::column3(in, q, count, t); };
#pragma GCC ivdep
  for (int64_t t = begin; t < end; ++t) {
    const Vec3<T> b = row(kBranchIn, t), w = row(kAngularIn, t), torque_bar = row(kTorqueBarIn, t);
    const SlotCotangents<T> bar = slot_law_backward<T>(
        b, row(kRelativeIn, t), row(kSpringIn, t), in[kOverlapIn * count + t], dt, normal_stiffness,
        tangential_stiffness, friction, row(kForceBarIn, t), row(kSpringBarIn, t));
    // torque: b̄ += τ̄ × F; relative = v_n − v_i − ω × b: ω̄ += v̄_rel × b, b̄ += ω × v̄_rel;
    // δ = R + t_m/2 − |b|: b̄ −= δ̄ n̂.
    const Vec3<T> branch_bar =
        bar.branch + cross(torque_bar, bar.force) + cross(w, bar.relative) - bar.overlap * bar.normal;
    const Vec3<T> angular_bar = cross(bar.relative, b);
    const T shares[kShares] = {branch_bar.x,  branch_bar.y,  branch_bar.z,   bar.relative.x,     bar.relative.y,
                               bar.relative.z, angular_bar.x, angular_bar.y, angular_bar.z,      bar.spring.x,
                               bar.spring.y,   bar.spring.z,  bar.overlap,   bar.dt,             bar.normal_stiffness,
                               bar.tangential_stiffness,      bar.friction};
#pragma GCC unroll 32
    for (int q = 0; q < kShares; ++q) share[q * count + t] = shares[q];
  }
}

// Inputs: those of node_sphere_forces, then the cotangents of its outputs: node force (n, 3), sphere
// force and torque (N, 3), springs (3, n, K); then two addends (n, 3) for the node position's and
// velocity's cotangents. Outputs: the cotangents of node position and velocity (n, 3), each its addend
// plus this law's share, sphere position, velocity and angular velocity (N, 3), radius (N,), springs
// (3, n, K) and scalars (5,) = Δt, k_n, k_t, μ, t_m. Slots that do not touch have zero outputs whatever
// their inputs. A caller may alias the two addends to the first two outputs and the springs' cotangent
// to the springs' output (XLA's input_output_aliases): the shares are then added and the springs
// written in place (a slot's spring cotangent is read in pass 1, before anything is written).
// Passes: which slots touch (vectorised), their inputs gathered (serial), their laws run backwards
// (vectorised), their shares summed per node and sphere in slot order (serial).
template <ffi::DataType dtype>
ffi::Error node_sphere_backward(ffi::Buffer<dtype> node_position, ffi::Buffer<dtype> node_velocity,
                                ffi::Buffer<dtype> sphere_position, ffi::Buffer<dtype> sphere_velocity,
                                ffi::Buffer<dtype> sphere_angular_velocity, ffi::Buffer<dtype> sphere_radius,
                                ffi::Buffer<ffi::S32> idx, ffi::Buffer<dtype> spring, ffi::Buffer<dtype> scalars,
                                ffi::Buffer<dtype> node_force_bar,
                                ffi::Buffer<dtype> sphere_force_bar, ffi::Buffer<dtype> sphere_torque_bar,
                                ffi::Buffer<dtype> spring_bar,
                                ffi::Buffer<dtype> node_position_addend, ffi::Buffer<dtype> node_velocity_addend,
                                ffi::ResultBuffer<dtype> node_position_out, ffi::ResultBuffer<dtype> node_velocity_out,
                                ffi::ResultBuffer<dtype> sphere_position_out,
                                ffi::ResultBuffer<dtype> sphere_velocity_out,
                                ffi::ResultBuffer<dtype> sphere_angular_out, ffi::ResultBuffer<dtype> radius_out,
                                ffi::ResultBuffer<dtype> spring_out,
                                ffi::ResultBuffer<dtype> scalars_out, ffi::ThreadPool pool) {
  using T = ffi::NativeType<dtype>;
  const SlotInputs<T> in = slot_inputs(node_position, node_velocity, sphere_position, sphere_velocity,
                                       sphere_angular_velocity, sphere_radius, idx, spring, scalars);
  const size_t node_rows = 3 * in.num_nodes, sphere_rows = 3 * in.num_spheres;
  if (!in.consistent || spring_bar.element_count() != spring.element_count() ||
      node_force_bar.element_count() != node_rows || node_position_addend.element_count() != node_rows ||
      node_velocity_addend.element_count() != node_rows || sphere_force_bar.element_count() != sphere_rows ||
      sphere_torque_bar.element_count() != sphere_rows) {
    return ffi::Error::InvalidArgument("node_sphere_backward: inconsistent array sizes");
  }
  const T* f_node_bar = node_force_bar.typed_data();
  const T* f_sphere_bar = sphere_force_bar.typed_data();
  const T* tau_bar = sphere_torque_bar.typed_data();
  const T* s_bar = spring_bar.typed_data();
  T* x_out = node_position_out->typed_data();
  T* v_out = node_velocity_out->typed_data();
  T* xs_out = sphere_position_out->typed_data();
  T* vs_out = sphere_velocity_out->typed_data();
  T* ws_out = sphere_angular_out->typed_data();
  T* r_out = radius_out->typed_data();
  T* s_out = spring_out->typed_data();
  T* scalar_out = scalars_out->typed_data();
  // The addends start the node sums (nothing to do where they are aliased to the outputs).
  const T* x_addend = node_position_addend.typed_data();
  const T* v_addend = node_velocity_addend.typed_data();
  if (x_addend != x_out) std::copy(x_addend, x_addend + 3 * in.num_nodes, x_out);
  if (v_addend != v_out) std::copy(v_addend, v_addend + 3 * in.num_nodes, v_out);
  std::fill(xs_out, xs_out + 3 * in.num_spheres, T(0));
  std::fill(vs_out, vs_out + 3 * in.num_spheres, T(0));
  std::fill(ws_out, ws_out + 3 * in.num_spheres, T(0));
  std::fill(r_out, r_out + in.num_spheres, T(0));
  std::fill(scalar_out, scalar_out + 5, T(0));

  thread_local std::vector<uint8_t> touching;
  touching.resize(size_t(in.m));
  // Which slots touch, then passes 1 and 2, each in two halves on two threads (parallel.h); each half
  // writes its own rows. (Pointers, not the thread_local vectors: a pool thread has its own.)
  uint8_t* touching_rows = touching.data();
  membrax::two_halves(pool, in.num_nodes, [&](int, int64_t begin, int64_t end) {
    touching_slots<T>(in.x, in.xs, in.radius, in.id, begin, end, in.capacity, in.num_spheres, in.half_thickness,
                      touching_rows);
  });
  // The touching slots in order, compacted without a branch.
  thread_local std::vector<int64_t> slots;
  slots.resize(size_t(in.m) + 1);
  int64_t* slot_of = slots.data();
  const uint8_t* touches = touching.data();
  int64_t count = 0;
  for (int64_t j = 0; j < in.m; ++j) {
    slot_of[count] = j;
    count += touches[j];
  }
  thread_local std::vector<T> scratch;
  scratch.resize(size_t((kGathered + kShares) * count));
  T* gathered = scratch.data();
  T* share = gathered + kGathered * count;
  // Pass 1: each touching slot's inputs, component-first; then pass 2, its law backwards.
  membrax::two_halves(pool, count, [&](int, int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t) {
      const int64_t j = slot_of[t], node = j / in.capacity, sphere = in.id[j];
      const SlotKinematics<T> kinematics = slot_kinematics(in.x, in.v, in.xs, in.vs, in.ws, node, sphere);
      const Vec3<T> b = kinematics.branch;
      // The slot's outputs: F on the node, −F on the sphere, torque −b × F on the sphere, spring s'.
      const Vec3<T> torque_bar = membrax::row3(tau_bar, sphere);
      // τ̄·(−b × F) = F·(b × τ̄)
      const Vec3<T> force_bar =
          (membrax::row3(f_node_bar, node) - membrax::row3(f_sphere_bar, sphere)) + cross(b, torque_bar);
      const Vec3<T> rows[7] = {b, kinematics.relative, membrax::column3(in.old_spring, 0, in.m, j),
                               kinematics.spin, force_bar, torque_bar, membrax::column3(s_bar, 0, in.m, j)};
      for (int q = 0; q < 7; ++q) {
        gathered[(3 * q) * count + t] = rows[q].x;
        gathered[(3 * q + 1) * count + t] = rows[q].y;
        gathered[(3 * q + 2) * count + t] = rows[q].z;
      }
      gathered[kOverlapIn * count + t] = in.radius[sphere] + in.half_thickness - std::sqrt(dot(b, b));
    }
    slot_laws_backward<T>(gathered, count, begin, end, in.dt, in.normal_stiffness, in.tangential_stiffness,
                          in.friction, share);
  });
  // Every spring cotangent is read (pass 1): zero the slots that do not touch; pass 3 writes the others.
  for (int c = 0; c < 3; ++c) {
    T* s_row = s_out + c * in.m;
    for (int64_t j = 0; j < in.m; ++j)
      if (!touches[j]) s_row[j] = T(0);
  }
  // Pass 3, in slot order: the shares to the nodes, the spheres and the scalars.
  for (int64_t t = 0; t < count; ++t) {
    const int64_t j = slot_of[t], node = j / in.capacity, sphere = in.id[j];
    // b = x_n − x_i and the relative velocity v_n − v_i − …: the node gets +, the sphere −.
    const Vec3<T> branch_bar = membrax::column3(share, kBranch, count, t);
    const Vec3<T> relative_bar = membrax::column3(share, kRelative, count, t);
    membrax::add3(x_out, node, branch_bar);
    membrax::add3(xs_out, sphere, T(-1) * branch_bar);
    membrax::add3(v_out, node, relative_bar);
    membrax::add3(vs_out, sphere, T(-1) * relative_bar);
    membrax::add3(ws_out, sphere, membrax::column3(share, kAngular, count, t));
    for (int c = 0; c < 3; ++c) s_out[c * in.m + j] = share[(kSpring + c) * count + t];
    const T overlap_bar = share[kOverlap * count + t];
    r_out[sphere] += overlap_bar;
    scalar_out[0] += share[kDt * count + t];
    scalar_out[1] += share[kNormalStiffness * count + t];
    scalar_out[2] += share[kTangentialStiffness * count + t];
    scalar_out[3] += share[kFriction * count + t];
    scalar_out[4] += T(0.5) * overlap_bar;
  }
  return ffi::Error::Success();
}

}  // namespace

MEMBRAX_DEFINE_HANDLERS(MembraxNodeSphereForces, node_sphere_forces);
MEMBRAX_DEFINE_HANDLERS(MembraxNodeSphereBackward, node_sphere_backward);
