#pragma once
/// @file svg_plot.hpp
/// A tiny self-contained SVG line-plot writer for evaluation figures (CCDFs of
/// localization errors, paper §IV-F): axes with "nice" ticks, linear or
/// logarithmic axes, grid, step or polyline series, legend. No dependencies;
/// the output opens in any browser and embeds in Markdown.
///
/// Usage:
///   SvgPlot plot;
///   plot.title = "CCDF of |eps_lat|"; plot.x_label = "|eps_lat| [m]";
///   plot.y_label = "P(error > x)"; plot.log_y = true;
///   plot.series.push_back(ccdf_series("full", lateral_errors));
///   write_svg(render_svg(plot), "ccdf_lat.svg");
#include <cstddef>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace polmap::eval {

/// One data series. Points with non-finite coordinates are skipped (the line
/// is broken there).
struct SvgSeries {
  std::string label;  ///< legend text; empty = not in the legend
  std::vector<double> x;
  std::vector<double> y;
  /// CSS colour; empty = the next colour of the palette (Tableau 10).
  std::string color;
  /// Step rendering ("post"): the value y[k] holds from x[k] to x[k+1]
  /// (distribution functions); otherwise straight segments between points.
  bool step = false;
  double stroke_width_px = 1.6;
  /// SVG stroke-dasharray, e.g. "6 3"; empty = solid.
  std::string dash;
};

/// A plot. Axis ranges default to the data extent (log axes: positive data only).
struct SvgPlot {
  std::string title;
  std::string x_label;
  std::string y_label;
  double width_px = 640.0;
  double height_px = 420.0;
  bool log_x = false;
  bool log_y = false;
  std::optional<double> x_min, x_max, y_min, y_max;
  bool legend = true;
  bool grid = true;
  std::vector<SvgSeries> series;
};

/// A mapping from data values to pixels along one axis.
struct AxisScale {
  double lo = 0.0;  ///< data value at px0 (> 0 for log axes)
  double hi = 1.0;  ///< data value at px1
  bool log = false;
  double px0 = 0.0;
  double px1 = 1.0;
  /// Pixel of a value; values outside [lo, hi] extrapolate linearly (in log
  /// space for log axes); non-positive values on a log axis map 1e6 px beyond
  /// px0, i.e. far outside the plot, so clipping hides them.
  [[nodiscard]] double to_px(double v) const;
};

/// Ticks 1, 2 or 5 × 10^k apart inside [lo, hi], at most max_ticks of them
/// (at least 2 when lo < hi and max_ticks >= 4); empty for an empty range.
[[nodiscard]] std::vector<double> nice_ticks(double lo, double hi, int max_ticks = 8);
/// Decade ticks 10^k within [lo, hi] (lo > 0); if fewer than two decades fall
/// inside, 1-2-5 ticks within the decades are added.
[[nodiscard]] std::vector<double> log_ticks(double lo, double hi);
/// Short tick label: at most 4 significant digits, no trailing zeros
/// ("0.05", "1", "2.5", "1e-05").
[[nodiscard]] std::string tick_label(double v, bool log_axis);

/// Complementary CDF of a sample as a step series: points (0, 1) and
/// (e_i, #{e > e_i} / n) for the sorted distinct values e_i, so the plotted
/// value at x is P(error > x) (paper §IV-F). Non-finite values are dropped;
/// negative values are allowed (the series then starts at the smallest value).
/// Large samples are thinned to at most max_points vertices, keeping the tail
/// (the last tail_points samples) exactly.
[[nodiscard]] SvgSeries ccdf_series(std::string label, std::span<const double> values,
                                    std::size_t max_points = 3000, std::size_t tail_points = 400);

/// Renders the plot as a complete SVG document (UTF-8 text).
[[nodiscard]] std::string render_svg(const SvgPlot& plot);
/// Escapes &, <, >, " and ' for SVG text and attributes.
[[nodiscard]] std::string svg_escape(std::string_view text);
/// Writes text to a file (atomically, via a temporary file). Throws IoError naming the file.
void write_svg(const std::string& svg, const std::filesystem::path& path);

}  // namespace polmap::eval
