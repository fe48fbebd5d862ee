#include "polmap/eval/svg_plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>

#include "polmap/schema/errors.hpp"

namespace polmap::eval {
namespace {

// Tableau 10: distinguishable, colour-blind friendlier than pure RGB.
constexpr const char* kPalette[] = {"#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f",
                                    "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"};

// Layout (pixels): room for tick labels on the left, axis label below, title above.
constexpr double kMarginLeft = 72.0;
constexpr double kMarginRight = 18.0;
constexpr double kMarginTop = 36.0;
constexpr double kMarginBottom = 52.0;

std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", v);
  return buf;
}

struct Range {
  double lo = std::numeric_limits<double>::infinity();
  double hi = -std::numeric_limits<double>::infinity();
  void add(double v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  [[nodiscard]] bool valid() const { return lo <= hi; }
};

/// Data range of one axis over all series (positive values only on log axes),
/// overridden by explicit limits and widened to tick boundaries.
std::pair<double, double> axis_range(const SvgPlot& plot, bool x_axis) {
  const bool log = x_axis ? plot.log_x : plot.log_y;
  Range r;
  for (const auto& s : plot.series) {
    const auto& v = x_axis ? s.x : s.y;
    const auto& other = x_axis ? s.y : s.x;
    for (std::size_t i = 0; i < v.size() && i < other.size(); ++i) {
      if (!std::isfinite(v[i]) || !std::isfinite(other[i])) continue;
      if (log && v[i] <= 0.0) continue;
      r.add(v[i]);
    }
  }
  const auto& user_lo = x_axis ? plot.x_min : plot.y_min;
  const auto& user_hi = x_axis ? plot.x_max : plot.y_max;
  double lo = r.valid() ? r.lo : (log ? 0.1 : 0.0);
  double hi = r.valid() ? r.hi : (log ? 1.0 : 1.0);
  if (user_lo && (!log || *user_lo > 0.0)) lo = *user_lo;
  if (user_hi && (!log || *user_hi > 0.0)) hi = *user_hi;
  if (hi < lo) std::swap(lo, hi);
  if (log) {
    if (hi <= lo) {
      lo /= 10.0;
      hi *= 10.0;
    }
    if (!user_lo) lo = std::pow(10.0, std::floor(std::log10(lo) + 1e-9));
    if (!user_hi) hi = std::pow(10.0, std::ceil(std::log10(hi) - 1e-9));
    if (hi <= lo) hi = lo * 10.0;
    return {lo, hi};
  }
  if (hi <= lo) {
    const double pad = lo == 0.0 ? 1.0 : std::abs(lo) * 0.1;
    lo -= pad;
    hi += pad;
  }
  const auto ticks = nice_ticks(lo, hi);
  if (ticks.size() >= 2) {
    const double step = ticks[1] - ticks[0];
    if (!user_lo) lo = std::floor(lo / step + 1e-9) * step;
    if (!user_hi) hi = std::ceil(hi / step - 1e-9) * step;
  }
  return {lo, hi};
}

}  // namespace

double AxisScale::to_px(double v) const {
  if (log) {
    if (!(v > 0.0)) return px0 + (px1 > px0 ? -1e6 : 1e6);
    const double a = std::log10(lo), b = std::log10(hi);
    return px0 + (std::log10(v) - a) / (b - a) * (px1 - px0);
  }
  return px0 + (v - lo) / (hi - lo) * (px1 - px0);
}

std::vector<double> nice_ticks(double lo, double hi, int max_ticks) {
  std::vector<double> out;
  if (!(hi > lo) || max_ticks < 2 || !std::isfinite(lo) || !std::isfinite(hi)) return out;
  const double raw = (hi - lo) / (max_ticks - 1);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double norm = raw / mag;
  const double choice = norm <= 1.0 ? 1.0 : norm <= 2.0 ? 2.0 : norm <= 5.0 ? 5.0 : 10.0;
  const double step = choice * mag;
  const double eps = step * 1e-9;
  // Below 1, divide by the exact integer 10^d instead of multiplying by 10^-d,
  // so ticks are the doubles nearest to the decimal values (0.6, not 0.6000000000000001).
  const double inv = mag < 1.0 ? std::round(1.0 / mag) : 0.0;
  for (double k = std::ceil(lo / step - 1e-9);; k += 1.0) {
    const double t = inv > 0.0 ? (k * choice) / inv : k * step;
    if (t > hi + eps) break;
    out.push_back(std::abs(t) < eps ? 0.0 : t);
  }
  return out;
}

std::vector<double> log_ticks(double lo, double hi) {
  std::vector<double> out;
  if (!(lo > 0.0) || !(hi > lo)) return out;
  const int k0 = static_cast<int>(std::ceil(std::log10(lo) - 1e-9));
  const int k1 = static_cast<int>(std::floor(std::log10(hi) + 1e-9));
  for (int k = k0; k <= k1; ++k) out.push_back(std::pow(10.0, k));
  if (out.size() >= 2) return out;
  out.clear();
  const int d0 = static_cast<int>(std::floor(std::log10(lo) + 1e-9));
  for (int k = d0; k <= k1 + 1; ++k) {
    for (double m : {1.0, 2.0, 5.0}) {
      const double t = m * std::pow(10.0, k);
      if (t >= lo * (1 - 1e-9) && t <= hi * (1 + 1e-9)) out.push_back(t);
    }
  }
  return out;
}

std::string tick_label(double v, bool log_axis) {
  (void)log_axis;
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

SvgSeries ccdf_series(std::string label, std::span<const double> values, std::size_t max_points,
                      std::size_t tail_points) {
  std::vector<double> v;
  v.reserve(values.size());
  for (double x : values) {
    if (std::isfinite(x)) v.push_back(x);
  }
  std::sort(v.begin(), v.end());
  SvgSeries s;
  s.label = std::move(label);
  s.step = true;
  if (v.empty()) return s;
  const double n = static_cast<double>(v.size());
  s.x.push_back(std::min(0.0, v.front()));
  s.y.push_back(1.0);
  // Vertices at the last index of each run of equal values: there the value
  // drops to #{e > v_i} / n = (n - i - 1) / n.
  std::vector<std::size_t> idx;
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (i + 1 < v.size() && v[i + 1] == v[i]) continue;
    idx.push_back(i);
  }
  std::size_t stride = 1;
  if (max_points > tail_points && idx.size() > max_points) {
    stride = (idx.size() - tail_points) / (max_points - tail_points) + 1;
  }
  for (std::size_t k = 0; k < idx.size(); ++k) {
    const bool in_tail = k + tail_points >= idx.size();
    if (!in_tail && k % stride != 0) continue;
    const std::size_t i = idx[k];
    s.x.push_back(v[i]);
    s.y.push_back((n - static_cast<double>(i) - 1.0) / n);
  }
  return s;
}

std::string svg_escape(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&apos;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string render_svg(const SvgPlot& plot) {
  const double W = plot.width_px, H = plot.height_px;
  const double left = kMarginLeft, right = W - kMarginRight;
  const double top = kMarginTop, bottom = H - kMarginBottom;
  const auto [xlo, xhi] = axis_range(plot, true);
  const auto [ylo, yhi] = axis_range(plot, false);
  const AxisScale xs{xlo, xhi, plot.log_x, left, right};
  const AxisScale ys{ylo, yhi, plot.log_y, bottom, top};

  std::ostringstream o;
  o << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
    << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << fmt(W) << "\" height=\"" << fmt(H)
    << "\" viewBox=\"0 0 " << fmt(W) << ' ' << fmt(H)
    << "\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"12\">\n"
    << "<rect x=\"0\" y=\"0\" width=\"" << fmt(W) << "\" height=\"" << fmt(H)
    << "\" fill=\"white\"/>\n"
    << "<defs><clipPath id=\"plot-area\"><rect x=\"" << fmt(left) << "\" y=\"" << fmt(top)
    << "\" width=\"" << fmt(right - left) << "\" height=\"" << fmt(bottom - top)
    << "\"/></clipPath></defs>\n";
  if (!plot.title.empty()) {
    o << "<text class=\"title\" x=\"" << fmt((left + right) / 2) << "\" y=\"" << fmt(top - 14)
      << "\" text-anchor=\"middle\" font-size=\"14\" font-weight=\"bold\">"
      << svg_escape(plot.title) << "</text>\n";
  }

  // Grid and ticks.
  const auto xt = plot.log_x ? log_ticks(xlo, xhi) : nice_ticks(xlo, xhi);
  const auto yt = plot.log_y ? log_ticks(ylo, yhi) : nice_ticks(ylo, yhi);
  o << "<g class=\"ticks\" stroke=\"#000\" stroke-width=\"1\">\n";
  for (double t : xt) {
    const double px = xs.to_px(t);
    if (plot.grid) {
      o << "<line x1=\"" << fmt(px) << "\" y1=\"" << fmt(top) << "\" x2=\"" << fmt(px) << "\" y2=\""
        << fmt(bottom) << "\" stroke=\"#ddd\"/>\n";
    }
    o << "<line x1=\"" << fmt(px) << "\" y1=\"" << fmt(bottom) << "\" x2=\"" << fmt(px)
      << "\" y2=\"" << fmt(bottom + 5) << "\"/>\n";
  }
  for (double t : yt) {
    const double py = ys.to_px(t);
    if (plot.grid) {
      o << "<line x1=\"" << fmt(left) << "\" y1=\"" << fmt(py) << "\" x2=\"" << fmt(right)
        << "\" y2=\"" << fmt(py) << "\" stroke=\"#ddd\"/>\n";
    }
    o << "<line x1=\"" << fmt(left - 5) << "\" y1=\"" << fmt(py) << "\" x2=\"" << fmt(left)
      << "\" y2=\"" << fmt(py) << "\"/>\n";
  }
  o << "</g>\n<g class=\"tick-labels\" fill=\"#000\">\n";
  for (double t : xt) {
    o << "<text x=\"" << fmt(xs.to_px(t)) << "\" y=\"" << fmt(bottom + 18)
      << "\" text-anchor=\"middle\">" << svg_escape(tick_label(t, plot.log_x)) << "</text>\n";
  }
  for (double t : yt) {
    o << "<text x=\"" << fmt(left - 8) << "\" y=\"" << fmt(ys.to_px(t) + 4)
      << "\" text-anchor=\"end\">" << svg_escape(tick_label(t, plot.log_y)) << "</text>\n";
  }
  o << "</g>\n";
  // Frame and axis labels.
  o << "<rect class=\"frame\" x=\"" << fmt(left) << "\" y=\"" << fmt(top) << "\" width=\""
    << fmt(right - left) << "\" height=\"" << fmt(bottom - top)
    << "\" fill=\"none\" stroke=\"#000\"/>\n";
  if (!plot.x_label.empty()) {
    o << "<text class=\"x-label\" x=\"" << fmt((left + right) / 2) << "\" y=\"" << fmt(H - 12)
      << "\" text-anchor=\"middle\">" << svg_escape(plot.x_label) << "</text>\n";
  }
  if (!plot.y_label.empty()) {
    const double cx = 16, cy = (top + bottom) / 2;
    o << "<text class=\"y-label\" x=\"" << fmt(cx) << "\" y=\"" << fmt(cy)
      << "\" text-anchor=\"middle\" transform=\"rotate(-90 " << fmt(cx) << ' ' << fmt(cy) << ")\">"
      << svg_escape(plot.y_label) << "</text>\n";
  }

  // Series (clipped to the plot area).
  std::vector<std::string> colors;
  std::size_t palette_i = 0;
  for (const auto& s : plot.series) {
    colors.push_back(!s.color.empty() ? s.color : kPalette[palette_i++ % std::size(kPalette)]);
  }
  o << "<g class=\"series\" clip-path=\"url(#plot-area)\" fill=\"none\">\n";
  for (std::size_t si = 0; si < plot.series.size(); ++si) {
    const auto& s = plot.series[si];
    std::string d;
    bool pen_down = false;
    const std::size_t n = std::min(s.x.size(), s.y.size());
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) {
        pen_down = false;
        continue;
      }
      const double px = xs.to_px(s.x[i]), py = ys.to_px(s.y[i]);
      // (Appends piecewise: GCC 12 warns falsely on `"M" + std::string`.)
      if (!pen_down) {
        d.append(1, 'M').append(fmt(px)).append(1, ' ').append(fmt(py));
        pen_down = true;
      } else if (s.step) {
        d.append(1, 'H').append(fmt(px)).append(1, 'V').append(fmt(py));
      } else {
        d.append(1, 'L').append(fmt(px)).append(1, ' ').append(fmt(py));
      }
    }
    if (d.empty()) continue;
    o << "<path class=\"series\" data-label=\"" << svg_escape(s.label) << "\" d=\"" << d
      << "\" stroke=\"" << svg_escape(colors[si]) << "\" stroke-width=\"" << fmt(s.stroke_width_px)
      << '"';
    if (!s.dash.empty()) o << " stroke-dasharray=\"" << svg_escape(s.dash) << '"';
    o << "/>\n";
  }
  o << "</g>\n";

  // Legend (top right inside the plot area).
  if (plot.legend) {
    std::size_t rows = 0, chars = 0;
    for (const auto& s : plot.series) {
      if (s.label.empty()) continue;
      ++rows;
      chars = std::max(chars, s.label.size());
    }
    if (rows > 0) {
      const double row_h = 17.0, w = 40.0 + 7.0 * static_cast<double>(chars);
      const double x0 = right - w - 8, y0 = top + 8;
      o << "<g class=\"legend\">\n<rect x=\"" << fmt(x0) << "\" y=\"" << fmt(y0) << "\" width=\""
        << fmt(w) << "\" height=\"" << fmt(row_h * static_cast<double>(rows) + 6)
        << "\" fill=\"white\" fill-opacity=\"0.85\" stroke=\"#999\"/>\n";
      std::size_t r = 0;
      for (std::size_t si = 0; si < plot.series.size(); ++si) {
        const auto& s = plot.series[si];
        if (s.label.empty()) continue;
        const double cy = y0 + 3 + row_h * (static_cast<double>(r) + 0.5);
        o << "<line x1=\"" << fmt(x0 + 6) << "\" y1=\"" << fmt(cy) << "\" x2=\"" << fmt(x0 + 30)
          << "\" y2=\"" << fmt(cy) << "\" stroke=\"" << svg_escape(colors[si])
          << "\" stroke-width=\"" << fmt(std::max(2.0, s.stroke_width_px)) << '"';
        if (!s.dash.empty()) o << " stroke-dasharray=\"" << svg_escape(s.dash) << '"';
        o << "/>\n<text x=\"" << fmt(x0 + 36) << "\" y=\"" << fmt(cy + 4) << "\">"
          << svg_escape(s.label) << "</text>\n";
        ++r;
      }
      o << "</g>\n";
    }
  }
  o << "</svg>\n";
  return o.str();
}

void write_svg(const std::string& svg, const std::filesystem::path& path) {
  const std::filesystem::path tmp = path.string() + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw IoError("cannot write " + tmp.string());
    f.write(svg.data(), static_cast<std::streamsize>(svg.size()));
    if (!f) throw IoError("cannot write " + tmp.string());
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec)
    throw IoError("cannot rename " + tmp.string() + " to " + path.string() + ": " + ec.message());
}

}  // namespace polmap::eval
