#pragma once
// Test support: the largest single allocation through the global operator new since the
// last reset (largest_allocation.cpp replaces operator new for the binary it is linked
// into), for tests that a limit applies before memory is reserved.
#include <cstddef>

namespace polmap::test {

void reset_largest_allocation();
[[nodiscard]] std::size_t largest_allocation();

}  // namespace polmap::test
