#pragma once
/// @file point_extractor.hpp
/// Point-shaped landmark candidates by pCFAR (paper §III-C1): the covariance C of
/// the cell under test is compared with the mean covariance Σ of its neighbourhood
/// by the Wishart distance, like a cell-averaging CFAR; detections are grouped into
/// connected components whose power-weighted centroids are the candidates.
///
/// Statistic. The paper's distance d(Σ, C) = q⁻¹(ln|Σ| + tr(Σ⁻¹C)) is the negative
/// Wishart log-likelihood of C under Σ (up to constants). As a function of Σ it is
/// smallest at Σ = C, where it equals q⁻¹(ln|C| + q), so its raw value depends on the
/// absolute power of the cell. We threshold the excess over that minimum, which is
/// the per-dimension log-likelihood ratio of "C is its own covariance" against "C
/// follows the neighbourhood":
///     d_ex = q⁻¹ (tr(Σ⁻¹C) − ln|Σ⁻¹C| − q) = q⁻¹ Σ_i (λ_i − ln λ_i − 1),
/// λ_i the eigenvalues of Σ⁻¹C. d_ex ≥ 0, = 0 iff C = Σ, is invariant to a common
/// power scale (and to any change of polarization basis), and grows with both a
/// power contrast and a polarimetric contrast (different mechanism at equal power).
/// Both matrices are diagonally loaded by ε = loading·σ² (σ² = the map's noise power
/// per component) so empty or rank-deficient cells stay finite.
///
/// d_ex is symmetric in brightness (a hole in bright clutter scores too), so a
/// detection also requires tr(C) ≥ contrast·tr(Σ) and a minimum SNR over noise.
///
/// Neighbourhood (CA-CFAR ring): the square of half-size training_radius_m around
/// the cell minus the guard square of half-size guard_radius_m; only observed cells
/// (N > 0) of the ring enter the mean (sums from one double-precision integral image
/// of all layers; only cells brighter than min_snr_db are tested). With line_aware,
/// detections are re-tested against line strips (PointExtractorConfig::line_aware).
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/polarimetry.hpp"
#include "polmap/schema/landmark.hpp"

namespace polmap::radar {

/// Paper form d = q⁻¹(ln|Σ| + tr(Σ⁻¹C)). Σ must be positive definite.
double wishart_distance(const Eigen::MatrixXcd& sigma, const Eigen::MatrixXcd& c);
/// Excess (log-likelihood-ratio) form d_ex = q⁻¹(tr(Σ⁻¹C) − ln|Σ⁻¹C| − q) ≥ 0
/// (file comment). Both must be positive definite.
double wishart_excess(const Eigen::MatrixXcd& sigma, const Eigen::MatrixXcd& c);

struct PointExtractorConfig {
  /// Guard half-size: a point's accumulated response (range PSF ± azimuth smear of
  /// near observations) stays within ~0.3 m, so it does not leak into the ring.
  double guard_radius_m = 0.4;
  /// Training half-size: the ring 0.4–1.5 m holds ~800 cells at 0.1 m, enough for a
  /// stable q×q mean, and is local enough to follow clutter changes.
  double training_radius_m = 1.5;
  /// Minimum observed ring cells as a fraction of the ring (border/unobserved areas).
  double min_training_fraction = 0.25;
  /// Threshold on d_ex (per dimension). 2.0 ≙ a 6.5 dB power contrast in every
  /// component (λ − ln λ − 1 = 2 at λ ≈ 4.5), or a strong contrast in fewer components.
  double threshold = 2.0;
  /// The cell must be at least this much brighter (trace) than the ring mean.
  double min_contrast_db = 3.0;
  /// Minimum trace(C)/(q·σ²) of a detection, dB (σ² = map noise power). C averages all
  /// looks, empty ones included: a landmark returns ≥ 15–20 dB in most looks that see
  /// it (0 dBsm at 50 m is 20 dB), while cells below 10 dB mean power owe it to a few
  /// floor exceedances (noise, aliased traffic, sidelobes). On simulated urban,
  /// industrial and rural drives, 3 → 10 dB removed 20–50 % of the candidates, nearly
  /// all off any object, and no true point (polmap detect-eval).
  double min_snr_db = 10.0;
  /// Diagonal loading of Σ and C in units of the noise power σ² per component.
  double loading = 1.0;
  /// Cells observed fewer times are not tested.
  std::uint32_t min_count = 1;
  /// Minimum persistence hits/N of a tested cell (looks with a stored bin over looks):
  /// a static landmark returns in most looks within its detection range, moving
  /// traffic whose Doppler aliases onto the static one (±2·v_ua) passes a cell in a
  /// few frames of hundreds.
  double min_persistence = 0.05;
  /// Line-aware neighbourhood (greatest-of): a cell that passes the ring test is
  /// tested again against the brightest of 8 line strips through it (directions
  /// 0°, 22.5°, ..., one cell wide, guard..training on both sides) when that strip is
  /// brighter than the ring. A speckle maximum on a wall, curb or guardrail is then
  /// compared with the structure it lies on, not with the empty ground beside it
  /// (the ring mixes both); a post in a fence still differs from the fence in mechanism.
  bool line_aware = true;
  /// Components larger than this (bounding-box diagonal) are extended objects
  /// (walls, guardrails: handled by the line extractor), not points.
  double max_extent_m = 1.5;
  /// Mechanism classification of the component's background-subtracted covariance.
  ScatteringClassConfig classes;
  /// Gridmap processing chunk: chunk_tiles × chunk_tiles tiles plus a halo.
  int chunk_tiles = 8;
};

/// pCFAR over a whole gridmap (processed in chunks with halos; candidates are
/// unique: each belongs to the chunk that contains its centroid). Sorted by
/// position (y, then x). Streams each chunk row by row from the map's tiles
/// (CovarianceGridmap::read_row) with a rolling integral image of 2·training + 2 rows,
/// so no dense raster of the chunk is built; the arithmetic is that of the raster path,
/// and the result equals extract_points_reference().
std::vector<PointCandidate> extract_points(const CovarianceGridmap& map,
                                           const PointExtractorConfig& cfg = {});

/// The straightforward version of extract_points(map): one dense CovarianceRaster per
/// chunk, processed by extract_points(raster). For tests and benchmarks.
std::vector<PointCandidate> extract_points_reference(const CovarianceGridmap& map,
                                                     const PointExtractorConfig& cfg = {});

/// pCFAR over one raster. If core is given, only components whose centroid cell
/// lies in core are returned.
std::vector<PointCandidate> extract_points(const CovarianceRaster& raster,
                                           const PointExtractorConfig& cfg = {},
                                           const CellBox* core = nullptr);

/// The d_ex image of a raster (CV_32F, row = iy − box.min_iy), 0 where not tested;
/// for inspection and tuning.
cv::Mat pcfar_statistic(const CovarianceRaster& raster, const PointExtractorConfig& cfg = {});

}  // namespace polmap::radar
