// The XLA FFI bindings of membrax's kernels, written once.
//
// A kernel's binding lists, in its parameters' order, what each parameter is: a buffer argument, a result
// buffer, the thread pool or a named int64 attribute. `binding_of(kernel, names...)` reads that list off the
// kernel's own parameter types, so that a binding cannot drift from its kernel, and
// MEMBRAX_DEFINE_HANDLERS(Name, kernel, names...) exports the handlers NameF32 and NameF64 of the kernel
// template's two instances. (XLA's own automatic binding, Ffi::BindTo, knows neither the thread pool
// nor attributes without a compile-time name.) A binding's methods consume it (they are rvalue-qualified)
// and it cannot be moved from outside the library, hence the temporaries passed along: C++17's
// guaranteed elision returns each method's result without a move.
#pragma once

#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>

#include "xla/ffi/api/ffi.h"

namespace membrax {

namespace ffi = xla::ffi;

// How one kernel parameter binds; a parameter of any other type does not compile. `names` points at the
// names of the attributes not bound yet; kNames is how many of them the parameter consumes.
template <typename Param>
struct BindsAs;

template <ffi::DataType T, size_t rank>
struct BindsAs<ffi::Buffer<T, rank>> {
  static constexpr int kNames = 0;
  template <typename Binding>
  static auto To(Binding&& binding, const char* const*) {
    return std::move(binding).template Arg<ffi::Buffer<T, rank>>();
  }
};

template <ffi::DataType T, size_t rank>
struct BindsAs<ffi::Result<ffi::Buffer<T, rank>>> {
  static constexpr int kNames = 0;
  template <typename Binding>
  static auto To(Binding&& binding, const char* const*) {
    return std::move(binding).template Ret<ffi::Buffer<T, rank>>();
  }
};

template <>
struct BindsAs<ffi::ThreadPool> {
  static constexpr int kNames = 0;
  template <typename Binding>
  static auto To(Binding&& binding, const char* const*) {
    return std::move(binding).template Ctx<ffi::ThreadPool>();
  }
};

template <>
struct BindsAs<int64_t> {
  static constexpr int kNames = 1;
  template <typename Binding>
  static auto To(Binding&& binding, const char* const* names) {
    return std::move(binding).template Attr<int64_t>(names[0]);
  }
};

template <typename Param, typename... Rest>
struct BindParams {
  template <typename Binding>
  static auto To(Binding&& binding, const char* const* names) {
    if constexpr (sizeof...(Rest) == 0) {
      return BindsAs<Param>::To(std::move(binding), names);
    } else {
      return BindParams<Rest...>::To(BindsAs<Param>::To(std::move(binding), names),
                                     names + BindsAs<Param>::kNames);
    }
  }
};

// The binding of `kernel`'s parameters, its int64_t attributes named by `names` in their order.
template <typename Result, typename... Params, typename... Names>
auto binding_of(Result (*)(Params...), Names... names) {
  static_assert(sizeof...(Names) == (0 + ... + int(std::is_same_v<Params, int64_t>)),
                "one name for each int64_t attribute, in the parameters' order");
  const char* const list[] = {names..., nullptr};
  return BindParams<Params...>::To(ffi::Ffi::Bind(), list);
}

}  // namespace membrax

// The handlers <name>F32 and <name>F64 of the kernel template `kernel` (membrax/native/__init__.py loads
// them by these names); the further arguments name its int64_t attributes. (The binding is in
// parentheses: XLA's macros would split it at its commas.)
#define MEMBRAX_DEFINE_HANDLERS(name, kernel, ...)                                                    \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(name##F32, kernel<xla::ffi::F32>,                                     \
                                (membrax::binding_of(kernel<xla::ffi::F32>, ##__VA_ARGS__)));         \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(name##F64, kernel<xla::ffi::F64>,                                     \
                                (membrax::binding_of(kernel<xla::ffi::F64>, ##__VA_ARGS__)))
