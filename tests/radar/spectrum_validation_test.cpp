// The gridmap rejects inconsistent spectra with a ValidationError naming the
// problem, and leaves the map unchanged.
#include <gtest/gtest.h>

#include <algorithm>
#include <numbers>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

PolSpectrum valid() {
  PolSpectrum s;
  s.num_range_bins = 100;
  for (int k = 0; k < 5; ++k) s.azimuth_bins_rad.push_back(static_cast<float>(0.05 * k));
  return s;
}

void expect_rejected(const PolSpectrum& s, const std::string& needle) {
  CovarianceGridmap map;
  try {
    map.add(s, {}, 0.0);
    FAIL() << "accepted; expected an error mentioning " << needle;
  } catch (const ValidationError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(SpectrumValidation, InconsistentSpectraAreRejected) {
  PolSpectrum one_beam = valid();
  one_beam.azimuth_bins_rad.resize(1);
  expect_rejected(one_beam, "fewer than 2 azimuth bins");

  PolSpectrum unsorted = valid();
  std::swap(unsorted.azimuth_bins_rad[1], unsorted.azimuth_bins_rad[2]);
  expect_rejected(unsorted, "not strictly ascending");

  PolSpectrum wide = valid();
  wide.azimuth_bins_rad = {-1.6F, 0.0F, 1.6F};
  expect_rejected(wide, "180");

  PolSpectrum bad_range = valid();
  bad_range.range_bin_m = 0.0;
  expect_rejected(bad_range, "range_bin_m");

  PolSpectrum bad_cell = valid();
  SpectrumCell c;
  c.range_bin = 100;  // == num_range_bins
  c.s[0] = cfloat(1.0F, 0.0F);
  bad_cell.cells.push_back(c);
  expect_rejected(bad_cell, "outside the declared bins");
}

TEST(SpectrumValidation, UnsortedCellsAreAcceptedAndMappedAlike) {
  PolSpectrum a = valid();
  for (int k = 4; k >= 0; --k) {
    SpectrumCell c;
    c.azimuth_bin = static_cast<std::uint16_t>(k);
    c.range_bin = static_cast<std::uint16_t>(50 - k);
    c.s[1] = cfloat(1.0F + k, 0.0F);
    a.cells.push_back(c);
  }
  PolSpectrum b = a;
  std::reverse(b.cells.begin(), b.cells.end());
  CovarianceGridmap ma, mb;
  ma.add(a, {1.0, 2.0, 0.3}, 0.0);
  mb.add(b, {1.0, 2.0, 0.3}, 0.0);
  const CellBox box = ma.bounds();
  for (int iy = box.min_iy; iy < box.max_iy; ++iy) {
    for (int ix = box.min_ix; ix < box.max_ix; ++ix) {
      ASSERT_EQ(ma.power(ix, iy), mb.power(ix, iy));
    }
  }
}

}  // namespace
}  // namespace polmap::radar
