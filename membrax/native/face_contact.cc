// Sphere contact on the membrane's faces, interior edges and interior nodes: forces, torques and the
// tangential springs of every occupied (feature, candidate) slot, in one pass per feature.
//
// An XLA FFI handler for the CPU (asynchronous: its loops run as two tasks on XLA's thread pool,
// parallel.h), compiled on first use by membrax/native/__init__.py; the law is that of
// membrax/membrane/face_contact.py (face_contact_forces), which remains the reference;
// face_contact_backward (below) is its reverse-mode rule. For each slot (feature f, candidate m) with
// sphere i = idx[f, m] < N:
//   the closest point x_p = Σ w_k x_k of the centre x_i on the feature (face: the foot of the perpendicular
//   on the triangle's plane, area coordinates w; edge: on its line, 1 − τ and τ; node: the node, 1), which
//   counts only where x_i lies in the feature's Voronoi region (tie band β = √ε of the dtype);
//   b = x_p − x_i, δ = R_i + t_m/2 − |b|, n̂ = b/|b|, F_n = k_n δ (touching: δ > 0 and |b| > 0),
//   v_t = Π_t[Σ w_k v_k − (v_i + ω_i × b)], s' = Coulomb-capped spring (contact_law.h), s' = 0 if not touching;
//   F = F_n n̂ + s' on the membrane, node k of the feature gets w_k F; −F on the sphere, torque b × (−F).
// Every formula is written as the JAX law writes it (same operations, same order), so the two agree to
// round-off; the region tests then decide the same ties.
//
// Sums without atomics, in the JAX law's order: a feature's share per node is summed over its slots in
// slot order (one row per feature node), then each node sums its features' rows through the mesh's
// incidence tables (corner_incidence, hinge_incidence) in their order; faces, then edges, then its own
// node slots. The spheres' force and torque are summed in slot order, faces, edges, nodes.
//
// Threads: each kind's features are split in two fixed halves (parallel.h: halves_on_pool here, two_halves
// in the backward), which write only their own features' springs and shares and keep their touching slots'
// reactions (the backward: cotangents) in lists of their own; after both, one thread adds the lists up in
// slot order (faces, edges, nodes, each kind's first half then its second) and sums the nodes' rows. So the
// sums are those of one pass over the slots, bit for bit, whichever thread ran which half.
//
// Inputs (T: float or double): node_position, node_velocity (n, 3); sphere_position, sphere_velocity,
// sphere_angular_velocity (N, 3); sphere_radius (N,); the slots face_idx (F, Mf), edge_idx (E, Me),
// node_idx (n, Mn), i32 padded with N; triangles (F, 3), edge_nodes (E, 4) = (u, v, o₁, o₂),
// neighbours (n, H) (each node's neighbours along interior edges, padded with n), corner_incidence (n, Jc)
// (entries < 3F: corner k = e / F of triangle e % F), hinge_incidence (n, Jh) (entries < 2E: the start
// (e < E) or end of edge e % E), all i32; springs (3, F, Mf), (3, E, Me), (3, n, Mn); scalars (5,) = Δt, k_n,
// k_t, μ, t_m.
// Outputs: node_force (n, 3), sphere_force (N, 3), sphere_torque (N, 3), the three springs'.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "contact_law.h"
#include "dual.h"
#include "ffi_bind.h"
#include "parallel.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

using membrax::cross;
using membrax::dot;
using membrax::row3;
using membrax::Vec3;

template <typename T>
struct Law {
  const T *x, *v, *xs, *vs, *ws, *radius;
  int64_t num_nodes, num_spheres;
  T dt, normal_stiffness, tangential_stiffness, friction, half_thickness;
  T band, upper_band;  // β and 1 − β, each rounded from double as the JAX law's Python floats are
};

// A touching slot's reaction on its sphere, −F and its torque b × (−F): kept by the slot loops (each loop,
// or half of one, its own list in slot order) and added to the spheres' sums after them, list by list.
template <typename T>
struct Reaction {
  int64_t sphere;
  Vec3<T> force, torque;
};

// A slot's spring set to zero (no contact), written only where it is not zero already: in a step's loop
// nearly every spring is, and a store would dirty its cache line all the same.
template <typename T>
inline void clear(T* spring, int64_t stride) {
  if ((spring[0] != T(0)) | (spring[stride] != T(0)) | (spring[2 * stride] != T(0)))
    spring[0] = spring[stride] = spring[2 * stride] = T(0);
}

// One slot's law from its sphere, the closest point's weights (count of them) and corners, and the
// carried spring; writes the new spring (component-first, stride m), appends the sphere's reaction where
// it touches and returns F on the membrane. `in_region`: whether the centre lies in the feature's region.
template <typename T, int kCount>
inline Vec3<T> slot_law(const Law<T>& law, int64_t sphere, Vec3<T> centre, const T (&weight)[kCount],
                        const Vec3<T> (&corner)[kCount], const int64_t (&node)[kCount], bool in_region,
                        T* spring, int64_t stride, std::vector<Reaction<T>>& reactions) {
  const Vec3<T> zero{T(0), T(0), T(0)};
  if (!in_region) {  // the reference's overlap −1: no force, a zero spring
    clear(spring, stride);
    return zero;
  }
  Vec3<T> contact_point = zero;
  for (int k = 0; k < kCount; ++k) contact_point = contact_point + weight[k] * corner[k];
  const Vec3<T> branch = contact_point - centre;  // from the sphere centre to the membrane point
  const T distance_sq = dot(branch, branch);
  const T distance = distance_sq == T(0) ? T(0) : std::sqrt(distance_sq);
  const T overlap = law.radius[sphere] + law.half_thickness - distance;
  if (!((overlap > T(0)) & (distance > T(0)))) {  // not touching (a NaN neither)
    clear(spring, stride);
    return zero;
  }
  // Touching (about one occupied slot in 300 at paper size): the law.
  Vec3<T> membrane_velocity = zero;
  for (int k = 0; k < kCount; ++k) membrane_velocity = membrane_velocity + weight[k] * row3(law.v, node[k]);
  const Vec3<T> normal = (T(1) / distance) * branch;
  const T normal_force = law.normal_stiffness * overlap;
  const Vec3<T> sphere_velocity = row3(law.vs, sphere) + cross(row3(law.ws, sphere), branch);
  const Vec3<T> relative = membrane_velocity - sphere_velocity;
  const Vec3<T> tangential = relative - dot(relative, normal) * normal;
  const Vec3<T> old{spring[0], spring[stride], spring[2 * stride]};
  const Vec3<T> updated = membrax::tangential_spring(old, normal, tangential, law.tangential_stiffness * law.dt,
                                                     law.friction * normal_force, true);
  spring[0] = updated.x;
  spring[stride] = updated.y;
  spring[2 * stride] = updated.z;
  const Vec3<T> force = normal_force * normal + updated;
  const Vec3<T> reaction = T(-1) * force;
  reactions.push_back({sphere, reaction, cross(branch, reaction)});
  return force;
}

// The forward kernel's visit of an occupied slot: the law (slot_law), the reactions kept in `reactions`.
template <typename T>
struct ForwardVisit {
  static constexpr bool kForward = true;
  const Law<T>& law;
  std::vector<Reaction<T>>& reactions;
  template <int kCount>
  Vec3<T> slot(int64_t sphere, Vec3<T> centre, const T (&weight)[kCount], const Vec3<T> (&corner)[kCount],
               const int64_t (&node)[kCount], bool in_region, T* spring, int64_t stride) {
    return slot_law<T, kCount>(law, sphere, centre, weight, corner, node, in_region, spring, stride, reactions);
  }
};

// Whether the sphere surely misses a feature that lies inside the ball (middle, extent): the closest point
// of any region of the feature is then farther from the centre than R + t_m/2, by a margin far above
// round-off, so the law gives no force and a zero spring, as the reference does in or out of the region.
// (Most occupied slots at paper size; a NaN goes on to the law, which carries it as the reference does.)
template <typename T>
inline bool out_of_reach(const Law<T>& law, int64_t sphere, Vec3<T> centre, Vec3<T> middle, T extent) {
  const Vec3<T> gap = centre - middle;
  const T limit = law.radius[sphere] + law.half_thickness + extent;
  return dot(gap, gap) > T(1.001) * (limit * limit);
}

// Whether any slot of a feature's row holds a sphere.
inline bool occupied(const int32_t* row, int64_t width, int64_t num_spheres) {
  bool any = false;
  for (int64_t m = 0; m < width; ++m) any |= row[m] < num_spheres;
  return any;
}

// Each slot of a feature's row in order: on_slot(sphere, centre, spring) for a sphere within reach of the
// ball (middle, extent); the spring of an empty or out-of-reach slot cleared on the forward pass.
template <bool kForward, typename T, typename OnSlot>
inline void for_each_slot(const Law<T>& law, const int32_t* row, int64_t width, T* spring_row, int64_t stride,
                          Vec3<T> middle, T extent, OnSlot on_slot) {
  for (int64_t m = 0; m < width; ++m) {
    T* s = spring_row + m;
    if (row[m] < law.num_spheres) {
      const int64_t sphere = row[m];
      const Vec3<T> centre = row3(law.xs, sphere);
      if (!out_of_reach(law, sphere, centre, middle, extent)) {
        on_slot(sphere, centre, s);
        continue;
      }
    }
    if constexpr (kForward) clear(s, stride);
  }
}

// The springs of a feature's row with no sphere, cleared on the forward pass.
template <bool kForward, typename T>
inline void clear_row(T* spring_row, int64_t width, int64_t stride) {
  if constexpr (kForward)
    for (int64_t m = 0; m < width; ++m) clear(spring_row + m, stride);
}

// A feature's K shares, written as K rows of 3 from share_row.
template <typename T, int K>
inline void write_shares(T* share_row, const Vec3<T> (&total)[K]) {
  for (int k = 0; k < K; ++k) {
    share_row[3 * k] = total[k].x;
    share_row[3 * k + 1] = total[k].y;
    share_row[3 * k + 2] = total[k].z;
  }
}

// The features of one kind in `range`, K nodes each, of `count` rows of `width` slots: on_row(i, row,
// stride, total) adds the forces of feature i's slots on its K nodes to total (zero to start) when its row
// holds a sphere; the springs of a row with none are cleared on the forward pass, which then writes each
// feature's total as its K rows of share (count, K, 3).
template <int K, typename Visit, typename T, typename OnRow>
inline void feature_rows(const Law<T>& law, const int32_t* idx, int64_t count, int64_t width, membrax::Range range,
                         T* spring, T* share, OnRow on_row) {
  const int64_t stride = count * width;
  for (int64_t i = range.begin; i < range.end; ++i) {
    Vec3<T> total[K];
    for (int k = 0; k < K; ++k) total[k] = Vec3<T>{T(0), T(0), T(0)};
    const int32_t* row = idx + i * width;
    if (occupied(row, width, law.num_spheres)) {
      on_row(i, row, stride, total);
    } else {
      clear_row<Visit::kForward>(spring + i * width, width, stride);
    }
    if constexpr (Visit::kForward) write_shares(share + 3 * K * i, total);
  }
}

// The faces in `range`: share (F, 3, 3), each triangle's force on its corners a, b, c summed over its slots.
template <typename T, typename Visit>
void face_slots(const Law<T>& law, const int32_t* idx, int64_t num_faces, int64_t width, membrax::Range range,
                const int32_t* triangles, T* spring, T* share, Visit& visit) {
  feature_rows<3, Visit>(law, idx, num_faces, width, range, spring, share,
                         [&](int64_t f, const int32_t* row, int64_t stride, Vec3<T>(&total)[3]) {
    const int64_t node[3] = {triangles[3 * f], triangles[3 * f + 1], triangles[3 * f + 2]};
    const Vec3<T> a = row3(law.x, node[0]), b = row3(law.x, node[1]), c = row3(law.x, node[2]);
    const Vec3<T> normal = cross(b - a, c - a);
    const T area_sq = dot(normal, normal);
    const T twice_area = area_sq == T(0) ? T(0) : std::sqrt(area_sq);
    const T inverse_area = T(1) / (twice_area > T(0) ? twice_area : T(1));
    const Vec3<T> unit = inverse_area * normal;
    const Vec3<T> corner[3] = {a, b, c};
    const Vec3<T> middle = T(1) / T(3) * ((a + b) + c);
    const Vec3<T> da = a - middle, db = b - middle, dc = c - middle;
    const T extent = std::sqrt(std::max(std::max(dot(da, da), dot(db, db)), dot(dc, dc)));
    for_each_slot<Visit::kForward>(law, row, width, spring + f * width, stride, middle, extent,
                                   [&](int64_t sphere, Vec3<T> centre, T* s) {
      const Vec3<T> foot = centre - dot(centre - a, unit) * unit;
      const T weight_a = dot(cross(c - b, foot - b), unit) * inverse_area;
      const T weight_b = dot(cross(a - c, foot - c), unit) * inverse_area;
      const T weight_c = (T(1) - weight_a) - weight_b;
      const bool inside = (weight_a > law.band) & (weight_b > law.band) & (weight_c > law.band) &
                          (twice_area > T(0));
      const T weight[3] = {weight_a, weight_b, weight_c};
      const Vec3<T> force = visit.slot(sphere, centre, weight, corner, node, inside, s, stride);
      for (int k = 0; k < 3; ++k) total[k] = total[k] + weight[k] * force;
    });
  });
}

// The interior edges in `range`: share (E, 2, 3), each edge's force on its ends u, v summed over its slots.
template <typename T, typename Visit>
void edge_slots(const Law<T>& law, const int32_t* idx, int64_t num_edges, int64_t width, membrax::Range range,
                const int32_t* edge_nodes, T* spring, T* share, Visit& visit) {
  feature_rows<2, Visit>(law, idx, num_edges, width, range, spring, share,
                         [&](int64_t e, const int32_t* row, int64_t stride, Vec3<T>(&total)[2]) {
    const int32_t* ids = edge_nodes + 4 * e;
    const int64_t node[2] = {ids[0], ids[1]};
    const Vec3<T> u = row3(law.x, ids[0]), v = row3(law.x, ids[1]);
    const Vec3<T> along = v - u;
    const T length_sq = dot(along, along);
    const T safe_length_sq = length_sq > T(0) ? length_sq : T(1);
    Vec3<T> inward[2];
    T safe_height_sq[2];
    for (int k = 0; k < 2; ++k) {
      const Vec3<T> out = row3(law.x, ids[2 + k]) - u;
      inward[k] = out - (dot(out, along) / safe_length_sq) * along;
      const T height_sq = dot(inward[k], inward[k]);
      safe_height_sq[k] = height_sq > T(0) ? height_sq : T(1);
    }
    const Vec3<T> corner[2] = {u, v};
    const Vec3<T> middle = T(0.5) * (u + v);
    const T extent = T(0.5) * std::sqrt(length_sq);
    for_each_slot<Visit::kForward>(law, row, width, spring + e * width, stride, middle, extent,
                                   [&](int64_t sphere, Vec3<T> centre, T* s) {
      const Vec3<T> from_u = centre - u;
      const T fraction = dot(from_u, along) / safe_length_sq;
      bool in_region = (fraction > law.band) & (fraction < law.upper_band) & (length_sq > T(0));
      for (int k = 0; k < 2; ++k) in_region &= dot(from_u, inward[k]) / safe_height_sq[k] <= law.band;
      const T weight[2] = {T(1) - fraction, fraction};
      const Vec3<T> force = visit.slot(sphere, centre, weight, corner, node, in_region, s, stride);
      for (int k = 0; k < 2; ++k) total[k] = total[k] + weight[k] * force;
    });
  });
}

// The interior nodes in `range`: share (n, 3), each node's own force summed over its slots.
template <typename T, typename Visit>
void node_slots(const Law<T>& law, const int32_t* idx, int64_t width, membrax::Range range,
                const int32_t* neighbours, int64_t num_neighbours, T* spring, T* share, Visit& visit) {
  const int64_t num_nodes = law.num_nodes;
  std::vector<Vec3<T>> spoke(static_cast<size_t>(num_neighbours));
  std::vector<T> safe_spoke_sq(static_cast<size_t>(num_neighbours));
  feature_rows<1, Visit>(law, idx, num_nodes, width, range, spring, share,
                         [&](int64_t n, const int32_t* row, int64_t stride, Vec3<T>(&total)[1]) {
    const Vec3<T> vertex = row3(law.x, n);
    const int32_t* around = neighbours + n * num_neighbours;
    for (int64_t h = 0; h < num_neighbours; ++h) {
      const bool present = around[h] < num_nodes;
      spoke[h] = (present ? row3(law.x, around[h]) : Vec3<T>{T(0), T(0), T(0)}) - vertex;
      const T spoke_sq = dot(spoke[h], spoke[h]);
      safe_spoke_sq[h] = spoke_sq > T(0) ? spoke_sq : T(1);
    }
    const Vec3<T> corner[1] = {vertex};
    const int64_t node[1] = {n};
    const T weight[1] = {T(1)};
    for_each_slot<Visit::kForward>(law, row, width, spring + n * width, stride, vertex, T(0),
                                   [&](int64_t sphere, Vec3<T> centre, T* s) {
      const Vec3<T> from_vertex = centre - vertex;
      bool in_region = true;
      for (int64_t h = 0; h < num_neighbours; ++h)
        in_region &= (dot(from_vertex, spoke[h]) / safe_spoke_sq[h] <= law.band) | (around[h] >= num_nodes);
      total[0] = total[0] + visit.slot(sphere, centre, weight, corner, node, in_region, s, stride);
    });
  });
}

// The springs (3, count, width) of the features in `range` copied from `from` to `to`, unless they are one
// buffer (aliased by the caller).
template <typename T>
void copy_springs(const T* from, T* to, int64_t count, int64_t width, membrax::Range range) {
  if (from == to) return;
  for (int c = 0; c < 3; ++c)
    std::copy(from + (c * count + range.begin) * width, from + (c * count + range.end) * width,
              to + (c * count + range.begin) * width);
}

// Each node's rows of `share` listed in its incidence row, summed left to right: row(e) maps an entry to
// its row, the zero row (after the others) for an entry that names no share; without a branch, which the
// mix of edge ends and opposite vertices in hinge_incidence would mispredict.
template <typename T, typename Row>
inline Vec3<T> incidence_sum(const T* share, const int32_t* incidence, int64_t width, Row row) {
  Vec3<T> total{T(0), T(0), T(0)};
  for (int64_t j = 0; j < width; ++j) total = total + row3(share, row(int64_t(incidence[j])));
  return total;
}

// The inputs both handlers read alike, checked once: the three slot tables (rows, width), the mesh's
// neighbour table (n rows), the triangles (F, 3) and interior edges (E, 4) of the slot tables' rows, the
// springs (3, rows, width), the spheres (N, 3) and the five scalars.
template <ffi::DataType dtype>
bool shared_inputs_agree(int64_t num_nodes, int64_t num_spheres, const ffi::Buffer<dtype>& sphere_position,
                         const ffi::Buffer<ffi::S32>& face_idx, const ffi::Buffer<ffi::S32>& edge_idx,
                         const ffi::Buffer<ffi::S32>& node_idx, const ffi::Buffer<ffi::S32>& triangles,
                         const ffi::Buffer<ffi::S32>& edge_nodes, const ffi::Buffer<ffi::S32>& neighbours,
                         const ffi::Buffer<dtype>& face_spring, const ffi::Buffer<dtype>& edge_spring,
                         const ffi::Buffer<dtype>& node_spring, const ffi::Buffer<dtype>& scalars) {
  const auto face_dims = face_idx.dimensions(), edge_dims = edge_idx.dimensions(), node_dims = node_idx.dimensions();
  const auto neighbour_dims = neighbours.dimensions();
  return face_dims.size() == 2 && edge_dims.size() == 2 && node_dims.size() == 2 && neighbour_dims.size() == 2 &&
         scalars.element_count() == 5 && node_dims[0] == num_nodes && neighbour_dims[0] == num_nodes &&
         triangles.element_count() == size_t(3 * face_dims[0]) &&
         edge_nodes.element_count() == size_t(4 * edge_dims[0]) &&
         face_spring.element_count() == size_t(3 * face_dims[0] * face_dims[1]) &&
         edge_spring.element_count() == size_t(3 * edge_dims[0] * edge_dims[1]) &&
         node_spring.element_count() == size_t(3 * node_dims[0] * node_dims[1]) &&
         sphere_position.element_count() == size_t(3 * num_spheres);
}

// The law's inputs: the node and sphere states, and the scalars Δt, k_n, k_t, μ, t_m (half of t_m kept: the
// mid-surface's reach), with the region tests' tie band β = √ε of T rounded from double.
template <ffi::DataType dtype>
Law<ffi::NativeType<dtype>> law_of(const ffi::Buffer<dtype>& node_position, const ffi::Buffer<dtype>& node_velocity,
                                   const ffi::Buffer<dtype>& sphere_position, const ffi::Buffer<dtype>& sphere_velocity,
                                   const ffi::Buffer<dtype>& sphere_angular_velocity,
                                   const ffi::Buffer<dtype>& sphere_radius, const ffi::Buffer<dtype>& scalars) {
  using T = ffi::NativeType<dtype>;
  const T* scalar = scalars.typed_data();
  const double band = std::sqrt(double(std::numeric_limits<T>::epsilon()));
  return Law<T>{node_position.typed_data(),
                node_velocity.typed_data(),
                sphere_position.typed_data(),
                sphere_velocity.typed_data(),
                sphere_angular_velocity.typed_data(),
                sphere_radius.typed_data(),
                int64_t(node_position.element_count() / 3),
                int64_t(sphere_radius.element_count()),
                scalar[0],
                scalar[1],
                scalar[2],
                scalar[3],
                T(0.5) * scalar[4],
                T(band),
                T(1.0 - band)};
}

// The inputs of both handlers, in order (file header): face_contact_backward takes those of
// face_contact_forces, then the cotangents of its outputs.
#define MEMBRAX_FACE_CONTACT_INPUTS(dtype)                                                                        \
  ffi::Buffer<dtype> node_position, ffi::Buffer<dtype> node_velocity, ffi::Buffer<dtype> sphere_position,       \
      ffi::Buffer<dtype> sphere_velocity, ffi::Buffer<dtype> sphere_angular_velocity,                           \
      ffi::Buffer<dtype> sphere_radius, ffi::Buffer<ffi::S32> face_idx, ffi::Buffer<ffi::S32> edge_idx,         \
      ffi::Buffer<ffi::S32> node_idx, ffi::Buffer<ffi::S32> triangles, ffi::Buffer<ffi::S32> edge_nodes,        \
      ffi::Buffer<ffi::S32> neighbours, ffi::Buffer<ffi::S32> corner_incidence,                                 \
      ffi::Buffer<ffi::S32> hinge_incidence, ffi::Buffer<dtype> face_spring, ffi::Buffer<dtype> edge_spring,    \
      ffi::Buffer<dtype> node_spring, ffi::Buffer<dtype> scalars

template <ffi::DataType dtype>
ffi::Future face_contact_forces(
    MEMBRAX_FACE_CONTACT_INPUTS(dtype),
    ffi::ResultBuffer<dtype> node_force, ffi::ResultBuffer<dtype> sphere_force, ffi::ResultBuffer<dtype> sphere_torque,
    ffi::ResultBuffer<dtype> new_face_spring, ffi::ResultBuffer<dtype> new_edge_spring,
    ffi::ResultBuffer<dtype> new_node_spring, ffi::ThreadPool pool) {
  using T = ffi::NativeType<dtype>;
  const int64_t num_nodes = node_position.element_count() / 3;
  const int64_t num_spheres = sphere_radius.element_count();
  const auto face_dims = face_idx.dimensions(), edge_dims = edge_idx.dimensions(), node_dims = node_idx.dimensions();
  const auto neighbour_dims = neighbours.dimensions(), corner_dims = corner_incidence.dimensions(),
             hinge_dims = hinge_incidence.dimensions();
  if (!shared_inputs_agree(num_nodes, num_spheres, sphere_position, face_idx, edge_idx, node_idx, triangles,
                           edge_nodes, neighbours, face_spring, edge_spring, node_spring, scalars) ||
      corner_dims.size() != 2 || hinge_dims.size() != 2 || corner_dims[0] != num_nodes ||
      hinge_dims[0] != num_nodes) {
    return membrax::failed(ffi::Error::InvalidArgument("face_contact_forces: inconsistent array sizes"));
  }
  const Law<T> law = law_of(node_position, node_velocity, sphere_position, sphere_velocity,
                            sphere_angular_velocity, sphere_radius, scalars);
  const int64_t num_faces = face_dims[0], face_width = face_dims[1];
  const int64_t num_edges = edge_dims[0], edge_width = edge_dims[1];
  const int64_t node_width = node_dims[1], num_neighbours = neighbour_dims[1];
  const int64_t corner_width = corner_dims[1], hinge_width = hinge_dims[1];
  const int32_t *face_ids = face_idx.typed_data(), *edge_ids = edge_idx.typed_data(), *node_ids = node_idx.typed_data();
  const int32_t *triangle_nodes = triangles.typed_data(), *edge_corners = edge_nodes.typed_data();
  const int32_t *around = neighbours.typed_data(), *corners = corner_incidence.typed_data(),
                *hinges = hinge_incidence.typed_data();
  const T *old_face = face_spring.typed_data(), *old_edge = edge_spring.typed_data(),
          *old_node = node_spring.typed_data();
  T *face_out = new_face_spring->typed_data(), *edge_out = new_edge_spring->typed_data(),
    *node_out = new_node_spring->typed_data();
  T *on_node = node_force->typed_data(), *on_sphere = sphere_force->typed_data(),
    *torque = sphere_torque->typed_data();
  const int64_t slots = num_faces * face_width + num_edges * edge_width + num_nodes * node_width;
  // What the two halves share with the tail: each kind's share rows (a zero row after the faces' and the
  // edges'), and each kind's touching reactions, per half.
  struct Scratch {
    std::unique_ptr<T[]> share;
    std::vector<Reaction<T>> reactions[3][2];
  };
  auto scratch = std::make_shared<Scratch>();
  scratch->share.reset(new T[size_t(9 * num_faces + 6 * num_edges + 3 * num_nodes + 6)]);
  T* face_share = scratch->share.get();
  T* edge_share = face_share + 9 * num_faces + 3;
  T* node_share = edge_share + 6 * num_edges + 3;
  // Each half: its faces, its edges and its nodes (parallel.h, half_range), the springs, shares and
  // reactions of its own slots. The springs are updated in their output buffers (aliased to the inputs by
  // the caller, or copied here): each slot reads its own spring and then writes it.
  auto half = [=](int h) {
    const membrax::Range faces = membrax::half_range(h, num_faces), edges = membrax::half_range(h, num_edges),
                         nodes = membrax::half_range(h, num_nodes);
    copy_springs(old_face, face_out, num_faces, face_width, faces);
    copy_springs(old_edge, edge_out, num_edges, edge_width, edges);
    copy_springs(old_node, node_out, num_nodes, node_width, nodes);
    ForwardVisit<T> face_visit{law, scratch->reactions[0][h]}, edge_visit{law, scratch->reactions[1][h]},
        node_visit{law, scratch->reactions[2][h]};
    face_slots(law, face_ids, num_faces, face_width, faces, triangle_nodes, face_out, face_share, face_visit);
    edge_slots(law, edge_ids, num_edges, edge_width, edges, edge_corners, edge_out, edge_share, edge_visit);
    node_slots(law, node_ids, node_width, nodes, around, num_neighbours, node_out, node_share, node_visit);
  };
  // After both halves: the spheres' sums over the reactions in slot order (faces, edges, nodes, each kind's
  // halves in order: the order of one pass over the slots), and the nodes' sums.
  auto tail = [=]() {
    std::fill(on_sphere, on_sphere + 3 * num_spheres, T(0));
    std::fill(torque, torque + 3 * num_spheres, T(0));
    for (const auto& kind : scratch->reactions) {
      for (const auto& reactions : kind) {
        for (const Reaction<T>& reaction : reactions) {
          membrax::add3(on_sphere, reaction.sphere, reaction.force);
          membrax::add3(torque, reaction.sphere, reaction.torque);
        }
      }
    }
    std::fill(face_share + 9 * num_faces, face_share + 9 * num_faces + 3, T(0));
    std::fill(edge_share + 6 * num_edges, edge_share + 6 * num_edges + 3, T(0));
    // Each node: its corners' face shares, its ends' edge shares, its own; in that order.
    for (int64_t n = 0; n < num_nodes; ++n) {
      // corner_index: e < F the triangles' first corners, then their second and third; padded with 3F.
      const Vec3<T> faces = incidence_sum<T>(face_share, corners + n * corner_width, corner_width, [=](int64_t e) {
        return e < num_faces ? 3 * e : e < 2 * num_faces ? 3 * (e - num_faces) + 1
                                   : e < 3 * num_faces ? 3 * (e - 2 * num_faces) + 2 : 3 * num_faces;
      });
      // hinge_index: the edges' starts, their ends, then the opposite vertices (no share); padded with 4E.
      const Vec3<T> edges = incidence_sum<T>(edge_share, hinges + n * hinge_width, hinge_width, [=](int64_t e) {
        return e < num_edges ? 2 * e : e < 2 * num_edges ? 2 * (e - num_edges) + 1 : 2 * num_edges;
      });
      const Vec3<T> total = (faces + edges) + row3(node_share, n);
      on_node[3 * n] = total.x;
      on_node[3 * n + 1] = total.y;
      on_node[3 * n + 2] = total.z;
    }
  };
  return membrax::halves_on_pool(pool, slots, half, tail);
}


// ---- The backward kernel: each touching slot's law on dual numbers, one input direction at a time.
//
// Reverse mode needs ū·J for the slot's outputs (its shares w_k F on its nodes, −F and b × (−F) on its
// sphere, its new spring s'), a function of a few dozen inputs (the feature's node positions and velocities,
// the sphere's position, velocity, spin and radius, the carried spring, Δt, k_n, k_t, μ, t_m): the scalar
// L = ū·outputs is evaluated on dual numbers once per input, seeded with that input's unit tangent, and its
// tangent is that input's cotangent. A few hundred slots touch at paper size, so this costs little. The
// regions and the touching test are decided on the values and held fixed, as the JAX law's selects are;
// every guarded norm and select takes the JAX law's branch (value-based), so the derivatives are its own.

using membrax::Dual;

template <typename T>
inline T value(T x) { return x; }
template <typename T>
inline T value(Dual<T> x) { return x.v; }

template <typename S>
inline S guarded_sqrt(S x) {  // √x, 0 (with a zero tangent) at x = 0: the JAX law's safe_norm
  using membrax::sqrt;
  using std::sqrt;
  return value(x) > decltype(value(x))(0) ? sqrt(x) : S{};
}

template <typename T>
inline Vec3<Dual<T>> lift(Vec3<T> a) {
  return {membrax::constant(a.x), membrax::constant(a.y), membrax::constant(a.z)};
}

// The slot's inputs, in their seeding order: corners (3K), corner velocities (3K), centre, sphere velocity,
// spin (3 each), radius, carried spring (3), Δt, k_n, k_t, μ, t_m.
template <int kCount>
constexpr int kInputs = 6 * kCount + 9 + 1 + 3 + 5;

// L = ū·(the slot's outputs) on inputs `in` (dual numbers); `bar`: the shares' cotangents per corner, then
// the sphere force's, the torque's and the spring's.
template <typename T, int kCount>
Dual<T> slot_objective(const Dual<T>* in, const Vec3<T> (&bar)[kCount + 3]) {
  using S = Dual<T>;
  auto vec = [in](int q) { return Vec3<S>{in[q], in[q + 1], in[q + 2]}; };
  Vec3<S> corner[kCount], velocity[kCount];
  for (int k = 0; k < kCount; ++k) {
    corner[k] = vec(3 * k);
    velocity[k] = vec(3 * kCount + 3 * k);
  }
  const int q = 6 * kCount;
  const Vec3<S> centre = vec(q), sphere_velocity = vec(q + 3), spin = vec(q + 6);
  const S radius = in[q + 9];
  const Vec3<S> spring = vec(q + 10);
  const S dt = in[q + 13], normal_stiffness = in[q + 14], tangential_stiffness = in[q + 15], friction = in[q + 16],
          thickness = in[q + 17];
  S weight[kCount];
  if constexpr (kCount == 3) {  // the area coordinates of the foot of the perpendicular
    const Vec3<S> a = corner[0], b = corner[1], c = corner[2];
    const Vec3<S> normal = cross(b - a, c - a);
    const S inverse_area = T(1) / guarded_sqrt(dot(normal, normal));  // > 0 in the face's region
    const Vec3<S> unit = inverse_area * normal;
    const Vec3<S> foot = centre - dot(centre - a, unit) * unit;
    weight[0] = dot(cross(c - b, foot - b), unit) * inverse_area;
    weight[1] = dot(cross(a - c, foot - c), unit) * inverse_area;
    weight[2] = (T(1) - weight[0]) - weight[1];
  } else if constexpr (kCount == 2) {  // τ along the edge
    const Vec3<S> along = corner[1] - corner[0];
    const S fraction = dot(centre - corner[0], along) / dot(along, along);
    weight[0] = T(1) - fraction;
    weight[1] = fraction;
  } else {
    weight[0] = membrax::constant(T(1));
  }
  Vec3<S> contact_point = lift(Vec3<T>{T(0), T(0), T(0)}), membrane_velocity = contact_point;
  for (int k = 0; k < kCount; ++k) {
    contact_point = contact_point + weight[k] * corner[k];
    membrane_velocity = membrane_velocity + weight[k] * velocity[k];
  }
  const Vec3<S> branch = contact_point - centre;
  const S distance = guarded_sqrt(dot(branch, branch));  // > 0: touching
  const Vec3<S> normal = (T(1) / distance) * branch;
  const S overlap = (radius + T(0.5) * thickness) - distance;
  const S normal_force = normal_stiffness * overlap;
  const Vec3<S> relative = membrane_velocity - (sphere_velocity + cross(spin, branch));
  const Vec3<S> tangential = relative - dot(relative, normal) * normal;
  // membrax.spheres.contact.tangential_spring_update, active.
  const S length = guarded_sqrt(dot(spring, spring));
  const Vec3<S> projected = spring - dot(spring, normal) * normal;
  const S projected_sq = dot(projected, projected), quarter = T(0.25) * length * length;
  const S denominator_sq = value(projected_sq) >= value(quarter) ? projected_sq : quarter;
  const bool positive = value(denominator_sq) > T(0);
  const S denominator = positive ? guarded_sqrt(denominator_sq) : S{};
  const Vec3<S> zero = lift(Vec3<T>{T(0), T(0), T(0)});
  const Vec3<S> direction = positive ? (T(1) / denominator) * projected : zero;
  const Vec3<S> trial = length * direction - (tangential_stiffness * dt) * tangential;
  const S trial_length = guarded_sqrt(dot(trial, trial));
  const S limit = friction * normal_force;
  const S slip = value(trial_length) > value(limit)
                     ? limit / (value(trial_length) > T(0) ? trial_length : membrax::constant(T(1)))
                     : membrax::constant(T(1));
  const Vec3<S> updated = slip * trial;
  const Vec3<S> force = normal_force * normal + updated;  // on the membrane
  const Vec3<S> reaction = S{T(-1), T(0)} * force;
  S total = dot(lift(bar[kCount]), reaction) + dot(lift(bar[kCount + 1]), cross(branch, reaction)) +
            dot(lift(bar[kCount + 2]), updated);
  for (int k = 0; k < kCount; ++k) total = total + dot(lift(bar[k]), weight[k] * force);
  return total;
}

// A touching slot's cotangents (gradient, its inputs' in seeding order, kInputs<count> of them) and where
// they go: its feature's count nodes and its sphere.
template <typename T>
struct SlotCotangents {
  int count;
  int64_t sphere, node[3];
  T gradient[kInputs<3>];
};

// The backward's visit of an occupied slot: where it touches, its spring's cotangent written and the
// cotangents of its other inputs kept in `touching`, in slot order (add_cotangents adds them up).
template <typename T>
struct BackwardVisit {
  static constexpr bool kForward = false;
  const Law<T>& law;
  const T *node_force_bar, *sphere_force_bar, *torque_bar, *spring_bar;  // spring_bar: this kind's
  const T* spring_base;                                                  // this kind's carried springs
  T* spring_out;
  std::vector<SlotCotangents<T>>& touching;

  template <int kCount>
  Vec3<T> slot(int64_t sphere, Vec3<T> centre, const T (&weight)[kCount], const Vec3<T> (&corner)[kCount],
               const int64_t (&node)[kCount], bool in_region, T* spring, int64_t stride) {
    const Vec3<T> zero{T(0), T(0), T(0)};
    if (!in_region) return zero;
    Vec3<T> contact_point = zero;  // as slot_law decides touching
    for (int k = 0; k < kCount; ++k) contact_point = contact_point + weight[k] * corner[k];
    const Vec3<T> branch = contact_point - centre;
    const T distance_sq = dot(branch, branch);
    const T distance = distance_sq == T(0) ? T(0) : std::sqrt(distance_sq);
    const T overlap = law.radius[sphere] + law.half_thickness - distance;
    if (!((overlap > T(0)) & (distance > T(0)))) return zero;
    const int64_t slot = spring - spring_base;
    constexpr int n_in = kInputs<kCount>;
    T values[n_in];
    for (int k = 0; k < kCount; ++k) {
      const Vec3<T> x = corner[k], v = row3(law.v, node[k]);
      const T rows[6] = {x.x, x.y, x.z, v.x, v.y, v.z};
      for (int c = 0; c < 3; ++c) {
        values[3 * k + c] = rows[c];
        values[3 * kCount + 3 * k + c] = rows[3 + c];
      }
    }
    const int q = 6 * kCount;
    const Vec3<T> sphere_rows[3] = {centre, row3(law.vs, sphere), row3(law.ws, sphere)};
    for (int r = 0; r < 3; ++r) {
      values[q + 3 * r] = sphere_rows[r].x;
      values[q + 3 * r + 1] = sphere_rows[r].y;
      values[q + 3 * r + 2] = sphere_rows[r].z;
    }
    values[q + 9] = law.radius[sphere];
    for (int c = 0; c < 3; ++c) values[q + 10 + c] = spring_base[c * stride + slot];
    const T scalars[5] = {law.dt, law.normal_stiffness, law.tangential_stiffness, law.friction,
                          T(2) * law.half_thickness};
    for (int c = 0; c < 5; ++c) values[q + 13 + c] = scalars[c];
    Vec3<T> bar[kCount + 3];
    for (int k = 0; k < kCount; ++k) bar[k] = row3(node_force_bar, node[k]);
    bar[kCount] = row3(sphere_force_bar, sphere);
    bar[kCount + 1] = row3(torque_bar, sphere);
    bar[kCount + 2] = {spring_bar[slot], spring_bar[stride + slot], spring_bar[2 * stride + slot]};
    SlotCotangents<T>& record = touching.emplace_back();
    record.count = kCount;
    record.sphere = sphere;
    T* gradient = record.gradient;
    Dual<T> in[n_in];
    for (int j = 0; j < n_in; ++j) in[j] = membrax::constant(values[j]);
    for (int j = 0; j < n_in; ++j) {
      in[j].d = T(1);
      gradient[j] = slot_objective<T, kCount>(in, bar).d;
      in[j].d = T(0);
    }
    for (int k = 0; k < kCount; ++k) record.node[k] = node[k];
    for (int c = 0; c < 3; ++c) spring_out[c * stride + slot] = gradient[q + 10 + c];
    return zero;
  }
};

// A touching slot's cotangents added to those of the nodes' positions and velocities, the spheres' position,
// velocity, spin and radius, and the scalars (all but its spring's, which its visit wrote).
template <typename T>
void add_cotangents(const SlotCotangents<T>& slot, T* const* out, T* scalars_bar) {
  const int count = slot.count, q = 6 * count;
  const T* gradient = slot.gradient;
  for (int k = 0; k < count; ++k) {
    membrax::add3(out[0], slot.node[k], Vec3<T>{gradient[3 * k], gradient[3 * k + 1], gradient[3 * k + 2]});
    membrax::add3(out[1], slot.node[k],
                  Vec3<T>{gradient[3 * count + 3 * k], gradient[3 * count + 3 * k + 1],
                          gradient[3 * count + 3 * k + 2]});
  }
  const int64_t sphere = slot.sphere;
  membrax::add3(out[2], sphere, Vec3<T>{gradient[q], gradient[q + 1], gradient[q + 2]});
  membrax::add3(out[3], sphere, Vec3<T>{gradient[q + 3], gradient[q + 4], gradient[q + 5]});
  membrax::add3(out[4], sphere, Vec3<T>{gradient[q + 6], gradient[q + 7], gradient[q + 8]});
  out[5][sphere] += gradient[q + 9];
  for (int c = 0; c < 5; ++c) scalars_bar[c] += gradient[q + 13 + c];
}

// Inputs: those of face_contact_forces, then the cotangents of its outputs (node force (n, 3), sphere force
// and torque (N, 3), the three springs). Outputs: the cotangents of its floating inputs: node position and
// velocity (n, 3), sphere position, velocity and spin (N, 3), radius (N,), the three springs and the scalars
// (5,) = Δt, k_n, k_t, μ, t_m. Slots that do not touch have zero cotangents whatever their inputs.
template <ffi::DataType dtype>
ffi::Error face_contact_backward(
    MEMBRAX_FACE_CONTACT_INPUTS(dtype),
    ffi::Buffer<dtype> node_force_bar, ffi::Buffer<dtype> sphere_force_bar, ffi::Buffer<dtype> sphere_torque_bar,
    ffi::Buffer<dtype> face_spring_bar, ffi::Buffer<dtype> edge_spring_bar, ffi::Buffer<dtype> node_spring_bar,
    ffi::ResultBuffer<dtype> node_position_out, ffi::ResultBuffer<dtype> node_velocity_out,
    ffi::ResultBuffer<dtype> sphere_position_out, ffi::ResultBuffer<dtype> sphere_velocity_out,
    ffi::ResultBuffer<dtype> sphere_angular_out, ffi::ResultBuffer<dtype> radius_out,
    ffi::ResultBuffer<dtype> face_spring_out, ffi::ResultBuffer<dtype> edge_spring_out,
    ffi::ResultBuffer<dtype> node_spring_out, ffi::ResultBuffer<dtype> scalars_out, ffi::ThreadPool pool) {
  using T = ffi::NativeType<dtype>;
  const int64_t num_nodes = node_position.element_count() / 3;
  const int64_t num_spheres = sphere_radius.element_count();
  const auto face_dims = face_idx.dimensions(), edge_dims = edge_idx.dimensions(), node_dims = node_idx.dimensions();
  const auto neighbour_dims = neighbours.dimensions();
  if (!shared_inputs_agree(num_nodes, num_spheres, sphere_position, face_idx, edge_idx, node_idx, triangles,
                           edge_nodes, neighbours, face_spring, edge_spring, node_spring, scalars) ||
      face_spring_bar.element_count() != face_spring.element_count() ||
      edge_spring_bar.element_count() != edge_spring.element_count() ||
      node_spring_bar.element_count() != node_spring.element_count() ||
      node_force_bar.element_count() != size_t(3 * num_nodes) ||
      sphere_force_bar.element_count() != size_t(3 * num_spheres) ||
      sphere_torque_bar.element_count() != size_t(3 * num_spheres)) {
    return ffi::Error::InvalidArgument("face_contact_backward: inconsistent array sizes");
  }
  const Law<T> law = law_of(node_position, node_velocity, sphere_position, sphere_velocity,
                            sphere_angular_velocity, sphere_radius, scalars);
  T* outputs[6] = {node_position_out->typed_data(), node_velocity_out->typed_data(),
                   sphere_position_out->typed_data(), sphere_velocity_out->typed_data(),
                   sphere_angular_out->typed_data(), radius_out->typed_data()};
  const int64_t sizes[6] = {3 * num_nodes, 3 * num_nodes, 3 * num_spheres, 3 * num_spheres, 3 * num_spheres,
                            num_spheres};
  for (int k = 0; k < 6; ++k) std::fill(outputs[k], outputs[k] + sizes[k], T(0));
  std::fill(scalars_out->typed_data(), scalars_out->typed_data() + 5, T(0));
  T* spring_outs[3] = {face_spring_out->typed_data(), edge_spring_out->typed_data(), node_spring_out->typed_data()};
  const size_t spring_sizes[3] = {face_spring.element_count(), edge_spring.element_count(),
                                  node_spring.element_count()};
  for (int k = 0; k < 3; ++k) std::fill(spring_outs[k], spring_outs[k] + spring_sizes[k], T(0));
  // The loops only read the springs (the visit's kForward is false).
  T* face_carried = const_cast<T*>(face_spring.typed_data());
  T* edge_carried = const_cast<T*>(edge_spring.typed_data());
  T* node_carried = const_cast<T*>(node_spring.typed_data());
  // Each kind's features in two halves on two threads (parallel.h): a touching slot's spring cotangent is
  // written by its half, its other cotangents kept in its half's list; the lists are then added up in slot
  // order, the first half's then the second's, as one pass over the slots would.
  std::vector<SlotCotangents<T>> touching[2];
  auto in_halves = [&](int64_t count, const T* carried, const T* carried_bar, T* out, const auto& loop) {
    touching[0].clear();
    touching[1].clear();
    membrax::two_halves(pool, count, [&](int half, int64_t begin, int64_t end) {
      BackwardVisit<T> visit{law, node_force_bar.typed_data(), sphere_force_bar.typed_data(),
                             sphere_torque_bar.typed_data(), carried_bar, carried, out, touching[half]};
      loop(membrax::Range{begin, end}, visit);
    });
    for (const auto& list : touching)
      for (const SlotCotangents<T>& slot : list) add_cotangents(slot, outputs, scalars_out->typed_data());
  };
  in_halves(face_dims[0], face_carried, face_spring_bar.typed_data(), spring_outs[0],
            [&](membrax::Range range, BackwardVisit<T>& visit) {
              face_slots(law, face_idx.typed_data(), face_dims[0], face_dims[1], range, triangles.typed_data(),
                         face_carried, static_cast<T*>(nullptr), visit);
            });
  in_halves(edge_dims[0], edge_carried, edge_spring_bar.typed_data(), spring_outs[1],
            [&](membrax::Range range, BackwardVisit<T>& visit) {
              edge_slots(law, edge_idx.typed_data(), edge_dims[0], edge_dims[1], range, edge_nodes.typed_data(),
                         edge_carried, static_cast<T*>(nullptr), visit);
            });
  in_halves(num_nodes, node_carried, node_spring_bar.typed_data(), spring_outs[2],
            [&](membrax::Range range, BackwardVisit<T>& visit) {
              node_slots(law, node_idx.typed_data(), node_dims[1], range, neighbours.typed_data(),
                         neighbour_dims[1], node_carried, static_cast<T*>(nullptr), visit);
            });
  return ffi::Error::Success();
}

#undef MEMBRAX_FACE_CONTACT_INPUTS

}  // namespace

MEMBRAX_DEFINE_HANDLERS(MembraxFaceContactForces, face_contact_forces);
MEMBRAX_DEFINE_HANDLERS(MembraxFaceContactBackward, face_contact_backward);
