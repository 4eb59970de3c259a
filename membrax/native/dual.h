// Dual numbers v + d ε (ε² = 0) for the backward kernels' directional derivatives.
//
// A conservative force F = −∇Φ has a symmetric Jacobian, so its reverse-mode product Jᵀ ū equals the
// directional derivative J ū: the backward kernel of such a force evaluates the forward formula once on
// dual numbers, positions x + ū ε, and reads the tangents. Each operation is inlined and branch-free so
// that the element loops calling it still vectorise.

#ifndef MEMBRAX_NATIVE_DUAL_H_
#define MEMBRAX_NATIVE_DUAL_H_

#include <cmath>

namespace membrax {

template <typename T>
struct Dual {  // an aggregate (no constructors), so that GCC keeps it in registers and vectorises loops
  T v, d;  // value, tangent
};

// A constant: zero tangent.
template <typename T>
constexpr Dual<T> constant(T value) {
  return {value, T(0)};
}

#define MEMBRAX_DUAL_INLINE __attribute__((always_inline)) inline

template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator+(Dual<T> a, Dual<T> b) { return {a.v + b.v, a.d + b.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator-(Dual<T> a, Dual<T> b) { return {a.v - b.v, a.d - b.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator-(Dual<T> a) { return {-a.v, -a.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator*(Dual<T> a, Dual<T> b) { return {a.v * b.v, a.d * b.v + a.v * b.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator/(Dual<T> a, Dual<T> b) {
  const T q = a.v / b.v;
  return {q, (a.d - q * b.d) / b.v};
}
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator+(Dual<T> a, T b) { return {a.v + b, a.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator+(T a, Dual<T> b) { return {a + b.v, b.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator-(Dual<T> a, T b) { return {a.v - b, a.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator-(T a, Dual<T> b) { return {a - b.v, -b.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator*(Dual<T> a, T b) { return {a.v * b, a.d * b}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator*(T a, Dual<T> b) { return {a * b.v, a * b.d}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator/(Dual<T> a, T b) { return {a.v / b, a.d / b}; }
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> operator/(T a, Dual<T> b) {
  const T q = a / b.v;
  return {q, -q * b.d / b.v};
}

// √a, with a zero tangent at a = 0 (the guarded norms of the JAX code have a zero gradient there).
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> sqrt(Dual<T> a) {
  const T root = std::sqrt(a.v);
  return {root, root > T(0) ? a.d / (T(2) * (root > T(0) ? root : T(1))) : T(0)};
}

// a if the condition holds, else b (a select, as jnp.where: the tangent of the branch taken).
template <typename T>
MEMBRAX_DUAL_INLINE Dual<T> select(bool condition, Dual<T> a, Dual<T> b) {
  return {condition ? a.v : b.v, condition ? a.d : b.d};
}

#undef MEMBRAX_DUAL_INLINE

}  // namespace membrax

#endif  // MEMBRAX_NATIVE_DUAL_H_
