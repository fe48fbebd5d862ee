// End to end on the simulator: a short urban drive streamed from polmap::sim into
// radar::process_drive (mapping mode) finds the poles, signs, trunks and facade
// features of the world truth at the right place with the right mechanism, and
// its lines cover the curbs and facades. Bounds are well below the figures
// `polmap detect-eval` reports on longer drives, so the test guards
// against regressions, not against the last percent.
#include <gtest/gtest.h>

#include "polmap/eval/detect_eval.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/truth.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::eval {
namespace {

TEST(DetectPipeline, SimulatedUrbanDriveYieldsTheTrueLandmarks) {
  sim::SimConfig scfg;
  sim::WorldSpec spec;
  spec.preset = "urban";
  spec.length_m = 400.0;
  spec.seed = 3;
  auto world = sim::make_world(spec, scfg);
  sim::DriveSimulator drive(world, scfg, 0);
  const radar::DriveProcessingResult res = radar::process_drive(drive);
  EXPECT_GT(res.stats.frames_mapped, 300U);
  EXPECT_EQ(res.stats.frames_without_pose, 0U);

  const WorldTruth truth =
      parse_world_truth(sim::world_truth_json(*world, 1, spec.seed), res.frame);
  std::vector<Eigen::Vector2d> traj;
  for (const auto& s : res.trajectory) traj.push_back(res.frame.to_local(s.lat_deg, s.lon_deg));
  const DetectEval ev = evaluate_detections(res.points, res.lines, truth, 0, traj);
  RecordProperty("point_recall", std::to_string(ev.points.recall));
  EXPECT_GT(ev.points.truth_observable, 30U);
  std::string by_class;
  for (const auto& [c, v] : ev.points.recall_by_class) {
    by_class += " " + c + " " + std::to_string(v.second) + "/" + std::to_string(v.first);
  }
  EXPECT_GE(ev.points.recall, 0.65)
      << by_class;  // occluded and rarely seen truth counts as observable
  EXPECT_GE(ev.points.structure_precision, 0.8);
  EXPECT_GE(ev.points.class_accuracy, 0.9);
  EXPECT_LE(ev.points.rms_error_m, 0.15);
  EXPECT_GE(ev.lines.coverage, 0.8);
  EXPECT_GE(ev.lines.precision, 0.6);
}

}  // namespace
}  // namespace polmap::eval
