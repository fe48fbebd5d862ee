#pragma once
/// @file line_extractor.hpp
/// Line-shaped landmark candidates (paper §III-C2), no polarimetry: the power
/// trace(C) in dB -> median filter -> Hessian-eigenvalue ridgeness -> threshold ->
/// skeleton (Guo–Hall thinning) -> probabilistic Hough segments, refined by a
/// weighted least-squares fit to the skeleton pixels that support them.
///
/// Power image. P = trace(C) in dB relative to a floor (floor_db_over_noise above
/// the map's noise power per component times q); cells below the floor or never
/// observed read as the floor, so the image is ≥ 0 dB and its edges carry no
/// artificial steps. In dB a curb 20 dB over the floor and a facade 40 dB over it
/// both become ridges of a few dB/cell², so one threshold serves both.
///
/// Ridgeness. Hessian H of the median-filtered dB image at scale σ (Gaussian
/// smoothing, then central second differences), eigenvalues λ1 ≤ λ2. A bright line
/// has λ1 ≪ 0, λ2 ≈ 0; a bright blob (a point landmark) has λ1 ≈ λ2 ≪ 0. Ridgeness
/// R = σ²·max(0, −λ1 − |λ2|) (scale-normalized, in dB; blobs score ~0). Only cells a
/// ridge centre passes through are kept (Steger's line points: the Newton step
/// −(∇·n)/λ1 to the profile maximum across the ridge, n the eigenvector of λ1, ends
/// inside the cell); this removes the flanks of step edges (borders of clutter areas),
/// which have a large λ1 but no maximum nearby. For a thin
/// line of height h dB and width w, R ≈ h·w/(σ√(2π)); e.g. h = 20 dB, w = 0.1 m,
/// σ = 0.15 m gives 5 dB.
///
/// Point-target spread. A strong point target (pole, trunk, facade corner) seen from
/// tens of metres smears along the azimuth over the beam and its sidelobes (±r·θ, e.g.
/// ±2–4 m at 30 m): a sharp ridge across the range direction, the same in every drive
/// over the route, through the target and behind opaque walls. Its power falls off
/// from the target on both sides; an extended object's does not (its level along the
/// line is flat up to speckle and bright spots). Segments whose dB profile decays with
/// the distance from its brightest point (LineExtractorConfig::spread_min_decay_db_per_m)
/// are dropped. On the simulated urban route these
/// were 70 % of one drive's line candidates and 98 % of the false line landmark length.
///
/// The gridmap is processed in chunks of chunk_tiles² tiles with a halo; segments
/// are clipped to their chunk and collinear pieces are merged across chunks.
#include <opencv2/core.hpp>
#include <vector>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/schema/landmark.hpp"

namespace polmap::radar {

struct LineExtractorConfig {
  /// Power floor above q·σ² (σ² = map noise power per component), dB. Cells below
  /// read as the floor: keeps speckle of empty looks out of the ridge filter.
  double floor_db_over_noise = 0.0;
  /// Cells of the gridmap with persistence hits/N below this read as empty. Off by
  /// default: extended objects are weak or aspect dependent (curbs rise above the
  /// floor only at short range, facades mostly near normal incidence), so their
  /// cells have low persistence too; 0.05 halved the line coverage of simulated
  /// urban and industrial drives while it removes traffic smears.
  double min_persistence = 0.0;
  /// Median filter aperture, cells (3 or 5): removes speckle spikes, keeps edges.
  int median_kernel_cells = 3;
  /// Gaussian scale of the Hessian, metres: about the accumulated width of a curb
  /// or wall response (range PSF 0.11 m plus pose and aspect smear).
  double sigma_m = 0.15;
  /// Ridgeness threshold (scale-normalized, dB); see the file comment for its scale.
  double ridge_threshold_db = 1.5;
  /// Hough accumulator resolution.
  double hough_rho_m = 0.1;
  double hough_theta_deg = 0.5;
  /// Minimum Hough votes, as metres of supporting skeleton.
  double hough_min_votes_m = 1.5;
  /// Minimum segment length (after merging) and the largest gap bridged inside a segment.
  double min_length_m = 2.0;
  double max_gap_m = 0.5;
  /// Skeleton pixels within this distance of a Hough segment refine it.
  double refine_radius_m = 0.2;
  /// End fitting: segment ends move along the line to where the power (dB over the
  /// floor, 3×3 maximum) falls below end_level_fraction of the segment's median
  /// (0.5: half the line's dB height, the geometric mean of line and floor power;
  /// robust to speckle dips), gaps up to max_gap_m bridged, at most
  /// max_end_extension_m beyond the Hough ends. The ridge filter alone loses ~σ per
  /// end and breaks on speckle.
  double end_level_fraction = 0.5;
  double max_end_extension_m = 2.0;
  /// Point-target spread rejection (file comment): a segment is dropped when its dB
  /// profile (3-cell maximum across the line, every cell) falls off with the distance
  /// from its brightest point by at least this much (Theil–Sen slope, dB/m). 3 dB/m: the
  /// azimuth spread of simulated point targets decays by ~10 dB/m (median; 3.5° beam,
  /// −17 dB sidelobes, seen from 20–50 m; the slowest ~2–3 dB/m, a weak broad spread
  /// under a strong neighbour), curbs and facades by ~0.5 dB/m; on a simulated urban
  /// drive it dropped 209 of 218 spread segments (95 % of their length) and 2.3 % of
  /// the true line length (4 dB/m: 204, 92 %, 1.8 %). 0 disables.
  double spread_min_decay_db_per_m = 3.0;
  /// Collinear merge (Hough duplicates, chunk borders): angle, lateral offset, gap.
  double merge_angle_deg = 2.0;
  double merge_offset_m = 0.15;
  double merge_gap_m = 0.5;
  /// Gridmap processing chunk: chunk_tiles × chunk_tiles tiles plus a halo.
  int chunk_tiles = 8;
  /// Filter the whole image instead of only the regions around cells above the floor
  /// (the straightforward version, for tests: both give the same images and lines).
  bool dense_filters = false;
};

/// Line candidates of a whole gridmap (metres in the map frame), sorted by start (y, x).
std::vector<LineCandidate> extract_lines(const CovarianceGridmap& map,
                                         const LineExtractorConfig& cfg = {});

/// Line candidates of a power image: CV_32F linear trace(C), row r ↔ iy = box.min_iy + r,
/// column c ↔ ix = box.min_ix + c (CovarianceGridmap::trace_image). noise_power: σ² per
/// component (0: floor at 1e-3 of the mean positive power); q: level dimension. If core
/// is given, segments are clipped to it.
std::vector<LineCandidate> extract_lines(const cv::Mat& power, const CellBox& box,
                                         double cell_size_m, double noise_power, int q,
                                         const LineExtractorConfig& cfg = {},
                                         const CellBox* core = nullptr);

/// The ridgeness image R (CV_32F, same layout as power), for inspection and tuning.
cv::Mat ridgeness_image(const cv::Mat& power, double cell_size_m, double noise_power, int q,
                        const LineExtractorConfig& cfg = {});

/// Merges collinear, overlapping or nearly touching segments (angle, offset and gap
/// limits of cfg); the merged segment spans the union of the projections on the
/// longer segment's line. Strength is length-weighted.
std::vector<LineCandidate> merge_collinear(std::vector<LineCandidate> lines,
                                           const LineExtractorConfig& cfg);

}  // namespace polmap::radar
