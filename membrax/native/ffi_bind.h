// The XLA FFI bindings of membrax's kernels, written once.
//
// A kernel's handler binds, in its parameters' order, buffers of the kernel's float type or of int32, the
// thread pool, attributes and result buffers. `Args<T, Real, Index, ...>::To(binding)` appends one `Arg` per kind
// (Real: a buffer of the float type T, Index: an int32 buffer) and `Rets<T, N>::To(binding)` N float results, so
// a handler's binding reads as the list of its parameters' kinds instead of one line per buffer. A
// binding's methods consume it (they are rvalue-qualified), hence the moves.
#pragma once

#include <utility>

#include "xla/ffi/api/ffi.h"

namespace membrax {

namespace ffi = xla::ffi;

struct Real {};   // a buffer of the kernel's float type
struct Index {};  // an int32 buffer (indices)

template <ffi::DataType T, typename Kind>
struct BufferOf {
  using type = ffi::Buffer<T>;
};

template <ffi::DataType T>
struct BufferOf<T, Index> {
  using type = ffi::Buffer<ffi::S32>;
};

template <ffi::DataType T, typename Kind, typename... Rest>
struct Args {
  // The binding is passed along as a temporary: its constructors are the library's own, and C++17's
  // guaranteed elision returns each method's result without one.
  template <typename Binding>
  static auto To(Binding&& binding) {
    if constexpr (sizeof...(Rest) == 0) {
      return std::move(binding).template Arg<typename BufferOf<T, Kind>::type>();
    } else {
      return Args<T, Rest...>::To(std::move(binding).template Arg<typename BufferOf<T, Kind>::type>());
    }
  }
};

template <ffi::DataType T, int N>
struct Rets {
  static_assert(N >= 1, "a kernel returns at least one buffer");
  template <typename Binding>
  static auto To(Binding&& binding) {
    if constexpr (N == 1) {
      return std::move(binding).template Ret<ffi::Buffer<T>>();
    } else {
      return Rets<T, N - 1>::To(std::move(binding).template Ret<ffi::Buffer<T>>());
    }
  }
};

}  // namespace membrax
