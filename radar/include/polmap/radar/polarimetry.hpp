#pragma once
/// @file polarimetry.hpp
/// Polarimetric levels, LR <-> HV basis transforms, covariance transforms and
/// the scattering-mechanism class of a covariance.
///
/// Conventions (shared with the simulator; reciprocal, backscatter alignment):
///   S_LL = (S_HH − S_VV + 2j·S_HV) / 2
///   S_RR = (S_VV − S_HH + 2j·S_HV) / 2
///   S_LR = S_RL = j·(S_HH + S_VV) / 2
/// Inverse: S_HH = (S_LL − S_RR − 2j·S_LR)/2, S_VV = (S_RR − S_LL − 2j·S_LR)/2,
///          S_HV = −j·(S_LL + S_RR)/2.
///
/// Level vectors (the q components a processing run uses, see PolLevel):
///   Full      k = (S_LL, (S_LR + S_RL)/√2, S_RR)      q = 3
///   DualLLLR  k = (S_LL, S_LR)                         q = 2
///   DualHHVV  k = (S_HH, S_VV)                         q = 2
///   SingleLR  k = S_LR;  SingleRR k = S_RR;  SingleHH k = S_HH   q = 1
/// The full-level reduction is the Pauli-like reciprocal reduction: it keeps the
/// span (‖k‖² = |S_LL|² + |S_LR|² + |S_RL|² + |S_RR|² when S_LR = S_RL), so
/// trace(C) is the total backscattered power, and with independent channel noise
/// of variance σ² every component of every level has noise variance σ² (the
/// linear channels synthesized from the four LR channels included), so levels
/// compare at equal noise. Partial levels use the raw measured channels
/// (S_LR, not the LR/RL average), emulating a sensor that only has those channels.
///
/// Linear-basis full vector: k_HV = (S_HH, √2·S_HV, S_VV); k_LR = U·k_HV with U
/// unitary (pauli_lr_from_hv()), so C_HV = U^H C_LR U (transform_covariance).
#include <Eigen/Core>
#include <array>
#include <complex>

#include "polmap/schema/landmark.hpp"
#include "polmap/schema/polarimetry.hpp"

namespace polmap::radar {

/// Number of stored upper-triangle covariance layers for dimension q: q(q+1)/2.
constexpr int num_layers(int q) { return q * (q + 1) / 2; }

/// Layer index of covariance element (i, j), i <= j, in row-major upper-triangle
/// order: (0,0), (0,1), ..., (0,q−1), (1,1), ..., (q−1,q−1).
constexpr int layer_index(int q, int i, int j) { return i * q - i * (i - 1) / 2 + (j - i); }

/// Level vector of a measured LR scattering vector (see file comment); q entries.
Eigen::VectorXcd level_vector(const ScatteringVector& omega, PolLevel level);

/// Fast single-precision variant for the gridmap hot path: writes pol_dimension(level)
/// components of the level vector of s = (S_LL, S_LR, S_RL, S_RR) into out.
void level_vector(const std::array<cfloat, 4>& s, PolLevel level, cfloat* out);

/// Linear-basis scattering matrix entries of a reciprocal target.
struct LinearScattering {
  cdouble hh;
  cdouble hv;
  cdouble vv;
};

/// LR -> HV (uses the LR/RL average, i.e. the reciprocal part).
LinearScattering hv_from_lr(const ScatteringVector& omega_lr);
/// HV -> LR (S_LR = S_RL).
ScatteringVector lr_from_hv(const LinearScattering& s);

/// U with k_LR = U·k_HV, k_LR = (S_LL, √2·S_LR, S_RR), k_HV = (S_HH, √2·S_HV, S_VV). Unitary.
Eigen::Matrix3cd pauli_lr_from_hv();
/// U^H: k_HV = U^H·k_LR.
Eigen::Matrix3cd pauli_hv_from_lr();

/// C' = A C A^H: the covariance of A·k when C is the covariance of k.
Eigen::MatrixXcd transform_covariance(const Eigen::MatrixXcd& c, const Eigen::MatrixXcd& a);

/// q×3 matrix P with k_level = P·k_full for a reciprocal target (signal relation;
/// for SingleLR/DualLLLR it maps to the LR/RL average). Use it to derive a partial
/// level's covariance from a full-level one: C_level = P C_full P^H.
Eigen::MatrixXcd level_projection(PolLevel level);

/// Odd- and even-bounce power of a covariance of the given level.
///   Full:     odd = C(1,1) = |S_LR+S_RL|²/2,  even = C(0,0) + C(2,2) = |S_LL|² + |S_RR|²
///   DualLLLR: odd = C(1,1) = |S_LR|²,         even = C(0,0) = |S_LL|²
///             (same ratio as full for reflection-symmetric targets, |S_LL| = |S_RR|)
///   DualHHVV: odd = |S_HH+S_VV|²/2,           even = |S_HH−S_VV|²/2  (the HV part is not seen)
///   single levels carry no mechanism information: odd = even = 0.
/// noise_power (σ² per component) is subtracted from each component first (clamped at 0).
struct MechanismPowers {
  double odd = 0.0;
  double even = 0.0;
};
MechanismPowers mechanism_powers(const Eigen::MatrixXcd& c, PolLevel level,
                                 double noise_power = 0.0);

struct ScatteringClassConfig {
  /// A mechanism dominates when its power exceeds the other's by this much.
  /// 3 dB (factor 2): a volume/diffuse target (random dipoles) has odd = even in
  /// the LR basis and classifies Mixed; a pole with 10 dB SNR classifies Odd.
  double dominance_db = 3.0;
};

/// Odd if odd ≥ dominance·even, Even if even ≥ dominance·odd, else Mixed; Unknown
/// for single-channel levels or zero power.
ScatteringClass classify_scattering(const Eigen::MatrixXcd& c, PolLevel level,
                                    const ScatteringClassConfig& cfg = {},
                                    double noise_power = 0.0);

}  // namespace polmap::radar
