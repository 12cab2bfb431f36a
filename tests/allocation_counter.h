// Counts the heap allocations of a test binary, so that a test can show that a call makes none:
//   const int64_t before = AllocationCount(); ...; EXPECT_EQ(AllocationCount(), before);
// It replaces the global operator new and delete, so include it from exactly one source file
// of a test executable.
#ifndef IMUCAL_TESTS_ALLOCATION_COUNTER_H_
#define IMUCAL_TESTS_ALLOCATION_COUNTER_H_

#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <new>

namespace imucal::test_support {
inline std::atomic<int64_t> g_allocations{0};
inline int64_t AllocationCount() { return g_allocations.load(std::memory_order_relaxed); }
}  // namespace imucal::test_support

// noinline: GCC would otherwise inline malloc/free pairs across the replacement and warn
// (-Wmismatched-new-delete) about its own view of them.
[[gnu::noinline]] void* operator new(std::size_t n) {
  imucal::test_support::g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
[[gnu::noinline]] void operator delete(void* p) noexcept { std::free(p); }
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept { std::free(p); }

#endif  // IMUCAL_TESTS_ALLOCATION_COUNTER_H_
