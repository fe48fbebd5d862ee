#pragma once
/// @file polarimetry.hpp
/// Polarization channels and polarimetric levels. Scattering vectors are in the
/// LR circular basis: Omega = (S_LL, S_LR, S_RL, S_RR) (Weishaupt et al. 2024, §III-B2).
#include <array>
#include <complex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace polmap {

using cfloat = std::complex<float>;
using cdouble = std::complex<double>;

/// Index of a channel in the LR-basis scattering vector.
enum class PolChannel : std::uint8_t { LL = 0, LR = 1, RL = 2, RR = 3 };
inline constexpr int kNumPolChannels = 4;

/// Scattering vector in the LR basis (S_LL, S_LR, S_RL, S_RR).
using ScatteringVector = std::array<cdouble, 4>;

/// Which polarimetric information a processing run uses (paper §IV-F).
enum class PolLevel : std::uint8_t {
  Full,      ///< LL, LR, RR (q = 3; LR = RL by reciprocity, averaged)
  DualLLLR,  ///< LL, LR (q = 2)
  DualHHVV,  ///< HH, VV (q = 2, linear basis)
  SingleLR,  ///< LR (q = 1)
  SingleRR,  ///< RR (q = 1)
  SingleHH,  ///< HH (q = 1, linear basis)
};

/// Number of components q of the level's scattering vector.
inline int pol_dimension(PolLevel level) {
  switch (level) {
    case PolLevel::Full:
      return 3;
    case PolLevel::DualLLLR:
    case PolLevel::DualHHVV:
      return 2;
    default:
      return 1;
  }
}

inline std::string_view to_string(PolLevel level) {
  switch (level) {
    case PolLevel::Full:
      return "full";
    case PolLevel::DualLLLR:
      return "ll-lr";
    case PolLevel::DualHHVV:
      return "hh-vv";
    case PolLevel::SingleLR:
      return "lr";
    case PolLevel::SingleRR:
      return "rr";
    case PolLevel::SingleHH:
      return "hh";
  }
  return "full";
}

/// Parses "full", "ll-lr", "hh-vv", "lr", "rr", "hh" (case-sensitive).
inline std::optional<PolLevel> parse_pol_level(std::string_view s) {
  for (PolLevel l : {PolLevel::Full, PolLevel::DualLLLR, PolLevel::DualHHVV, PolLevel::SingleLR,
                     PolLevel::SingleRR, PolLevel::SingleHH}) {
    if (to_string(l) == s) return l;
  }
  return std::nullopt;
}

inline const std::vector<std::string>& pol_level_names() {
  static const std::vector<std::string> names{"full", "ll-lr", "hh-vv", "lr", "rr", "hh"};
  return names;
}

}  // namespace polmap
