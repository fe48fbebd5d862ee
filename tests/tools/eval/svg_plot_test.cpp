// SVG plot writer: tick math, axis mapping, CCDF series against a brute-force
// definition, rendered document structure, escaping.
#include "polmap/eval/svg_plot.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <regex>
#include <sstream>

#include "test_dir.hpp"

namespace polmap::eval {
namespace {

int count(const std::string& s, const std::string& needle) {
  int n = 0;
  for (std::size_t p = s.find(needle); p != std::string::npos; p = s.find(needle, p + 1)) ++n;
  return n;
}

TEST(NiceTicks, StepsAreOneTwoFiveTimesPowerOfTen) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int trial = 0; trial < 500; ++trial) {
    const double a = std::pow(10.0, u(rng)) * (trial % 3 == 0 ? -1 : 1);
    const double b = a + std::pow(10.0, u(rng));
    const auto t = nice_ticks(a, b, 8);
    ASSERT_GE(t.size(), 2u) << a << " " << b;
    ASSERT_LE(t.size(), 8u);
    const double step = t[1] - t[0];
    const double mant = step / std::pow(10.0, std::floor(std::log10(step) + 1e-9));
    EXPECT_TRUE(std::abs(mant - 1) < 1e-6 || std::abs(mant - 2) < 1e-6 ||
                std::abs(mant - 5) < 1e-6 || std::abs(mant - 10) < 1e-6)
        << step;
    for (std::size_t i = 0; i < t.size(); ++i) {
      EXPECT_GE(t[i], a - 1e-9 * step);
      EXPECT_LE(t[i], b + 1e-9 * step);
      if (i > 0) {
        EXPECT_NEAR(t[i] - t[i - 1], step, 1e-9 * step);
      }
      // Ticks are multiples of the step (to rounding of k·step).
      EXPECT_NEAR(t[i] / step, std::round(t[i] / step), 1e-6 + 1e-9 * std::abs(t[i] / step));
    }
  }
  EXPECT_EQ(nice_ticks(0.0, 1.0, 6), (std::vector<double>{0.0, 0.2, 0.4, 0.6, 0.8, 1.0}));
  EXPECT_TRUE(nice_ticks(1.0, 1.0).empty());
}

TEST(LogTicks, DecadesOrOneTwoFive) {
  EXPECT_EQ(log_ticks(1e-3, 1.0), (std::vector<double>{1e-3, 1e-2, 1e-1, 1.0}));
  const auto t = log_ticks(0.15, 0.9);  // no decade inside: 1-2-5 ticks
  EXPECT_EQ(t, (std::vector<double>{0.2, 0.5}));
  EXPECT_TRUE(log_ticks(-1.0, 1.0).empty());
}

TEST(AxisScale, LinearAndLogMapping) {
  const AxisScale lin{0.0, 2.0, false, 100.0, 300.0};
  EXPECT_DOUBLE_EQ(lin.to_px(0.0), 100.0);
  EXPECT_DOUBLE_EQ(lin.to_px(1.0), 200.0);
  EXPECT_DOUBLE_EQ(lin.to_px(2.0), 300.0);
  // y axis: bottom pixel at lo.
  const AxisScale lg{1e-3, 1.0, true, 400.0, 100.0};
  EXPECT_NEAR(lg.to_px(1e-3), 400.0, 1e-9);
  EXPECT_NEAR(lg.to_px(1e-2), 300.0, 1e-9);
  EXPECT_NEAR(lg.to_px(1.0), 100.0, 1e-9);
  EXPECT_NEAR(lg.to_px(std::sqrt(10.0) * 1e-2), 250.0, 1e-9);
  EXPECT_GT(lg.to_px(0.0), 1e5);  // beyond the bottom edge, clipped away
}

TEST(Ccdf, MatchesBruteForceDefinition) {
  std::mt19937 rng(7);
  std::exponential_distribution<double> e(10.0);
  std::vector<double> v(700);
  for (auto& x : v) x = std::round(e(rng) * 100.0) / 100.0;  // ties on purpose
  v.push_back(std::nan(""));
  const SvgSeries s = ccdf_series("lat", v);
  ASSERT_EQ(s.x.size(), s.y.size());
  EXPECT_TRUE(s.step);
  EXPECT_EQ(s.x.front(), 0.0);
  EXPECT_EQ(s.y.front(), 1.0);
  const double n = 700.0;
  for (std::size_t k = 1; k < s.x.size(); ++k) {
    int greater = 0;
    for (std::size_t i = 0; i < 700; ++i) greater += v[i] > s.x[k] ? 1 : 0;
    EXPECT_DOUBLE_EQ(s.y[k], greater / n) << s.x[k];
    EXPECT_GT(s.x[k], s.x[k - 1] - (k == 1 ? 1.0 : 0.0));
  }
  EXPECT_EQ(s.y.back(), 0.0);
}

TEST(Ccdf, ThinsLargeSamplesButKeepsTheTail) {
  std::vector<double> v(20000);
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = static_cast<double>(i) * 1e-4;
  const SvgSeries s = ccdf_series("x", v, 1000, 200);
  EXPECT_LE(s.x.size(), 1001u + 200u);
  // The last 200 sample points are all present.
  for (std::size_t i = 0; i < 200; ++i) {
    const double x = v[v.size() - 1 - i];
    EXPECT_NE(std::find(s.x.begin(), s.x.end(), x), s.x.end()) << x;
  }
  EXPECT_EQ(s.x.back(), v.back());
  EXPECT_EQ(s.y.back(), 0.0);
}

TEST(RenderSvg, DocumentHasAxesSeriesAndLegend) {
  SvgPlot p;
  p.title = "CCDF <lat> & more";
  p.x_label = "|eps_lat| [m]";
  p.y_label = "P(error > x)";
  p.log_y = true;
  std::vector<double> a{0.01, 0.02, 0.05, 0.1, 0.3};
  std::vector<double> b{0.02, 0.04, 0.08, 0.2, 0.6};
  p.series.push_back(ccdf_series("full", a));
  p.series.push_back(ccdf_series("rr", b));
  p.series.back().dash = "6 3";
  const std::string svg = render_svg(p);
  EXPECT_EQ(svg.rfind("<?xml", 0), 0u);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
  EXPECT_EQ(count(svg, "<path class=\"series\""), 2);
  EXPECT_NE(svg.find("CCDF &lt;lat&gt; &amp; more"), std::string::npos);
  EXPECT_EQ(svg.find("<lat>"), std::string::npos);
  EXPECT_NE(svg.find("class=\"legend\""), std::string::npos);
  EXPECT_NE(svg.find(">full</text>"), std::string::npos);
  EXPECT_NE(svg.find(">rr</text>"), std::string::npos);
  EXPECT_NE(svg.find("stroke-dasharray=\"6 3\""), std::string::npos);
  // Log y axis from 0.1 (smallest positive CCDF value 1/5 -> decade 0.1) to 1.
  EXPECT_NE(svg.find(">0.1</text>"), std::string::npos);
  EXPECT_NE(svg.find(">1</text>"), std::string::npos);
  // Balanced group tags.
  EXPECT_EQ(count(svg, "<g "), count(svg, "</g>"));
  // Step paths use horizontal/vertical commands only after the move.
  const std::regex step_path("d=\"M[0-9.\\- ]+(H[0-9.\\-]+V[0-9.\\-]+)+\"");
  EXPECT_TRUE(std::regex_search(svg, step_path));
}

TEST(RenderSvg, EmptyAndDegenerateInputsStillRender) {
  SvgPlot p;
  EXPECT_NE(render_svg(p).find("</svg>"), std::string::npos);
  SvgSeries s;
  s.label = "const";
  s.x = {1.0, 1.0};
  s.y = {2.0, 2.0};
  p.series.push_back(s);
  const std::string svg = render_svg(p);
  EXPECT_EQ(count(svg, "<path class=\"series\""), 1);
  EXPECT_EQ(svg.find("nan"), std::string::npos);
  EXPECT_EQ(svg.find("inf"), std::string::npos);
}

TEST(WriteSvg, WritesTheFile) {
  const util::ScopedTempDir owned(polmap::test::unique_test_dir("svg-plot"));
  const auto dir = owned.path();
  const auto path = dir / "x.svg";
  write_svg("<svg/>", path);
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  EXPECT_EQ(ss.str(), "<svg/>");
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace polmap::eval
