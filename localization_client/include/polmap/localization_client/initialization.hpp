#pragma once
/// @file initialization.hpp
/// When a wide-gate match is trusted enough to start tracking (Localizer status
/// Initializing / Lost) or to re-anchor a tracking localizer (relocalization check).
///
/// A single match is weak evidence where the map repeats itself: along a guardrail
/// (posts every 2–4 m) or a tree alley the matcher's candidates one spacing apart
/// differ by one or two cost units, and which of them wins flips from one extraction
/// to the next with odometry noise in the local map. So a match *counts* only when it
/// is unambiguous by a clear margin with enough associations, and tracking starts only
/// when counting matches agreed with each other over enough driving that new,
/// non-repeating landmarks had to fit too. Pure value logic, no I/O.
#include <optional>

#include "polmap/localization_client/matcher.hpp"
#include "polmap/schema/pose2.hpp"

namespace polmap::loc {

/// Parameters (LocalizerConfig carries them; defaults documented there).
struct InitializationConfig {
  /// A counting match has at least this many point associations ...
  int min_point_matches = 6;
  /// ... and beats its best distinct alternative by this cost margin (matcher cost
  /// units, about one unmatched cluster each).
  double min_margin = 3.0;
  /// Tracking starts after this many agreeing counting matches ...
  int confirmations = 2;
  /// ... spanning at least this much driving (odometry distance).
  double min_travel_m = 20.0;
  /// Two map <- odometry transforms agree when they put the current vehicle pose
  /// within these of each other.
  double agreement_xy_m = 1.0;
  double agreement_yaw_rad = 0.0175;
};

/// Cost by which m beats its best distinct alternative; +inf when there is none.
[[nodiscard]] double clear_margin(const MatchResult& m);

/// Whether m is evidence on its own: status Ok, min_point_matches associations and a
/// clear margin of min_margin.
[[nodiscard]] bool counts_for_initialization(const MatchResult& m, const InitializationConfig& cfg);

/// Whether T_map_odom_a and T_map_odom_b place the vehicle (at T_odom_vehicle) within
/// the agreement tolerances of each other.
[[nodiscard]] bool poses_agree(const Pose2& T_map_odom_a, const Pose2& T_map_odom_b,
                               const Pose2& T_odom_vehicle, const InitializationConfig& cfg);

/// The streak of agreeing matches during initialization. Each extraction's wide-gate
/// match goes through add():
///  - a counting match that agrees with the streak confirms it; one that does not
///    starts a new streak at its pose;
///  - a match that does not count but whose pose agrees with the streak continues it
///    without confirming (on a landmark-poor road the matches between two counting ones
///    often have 4–5 associations; ending the streak there let the search gate grow
///    until an alias far from the truth won);
///  - any other match ends the streak.
class InitializationStreak {
 public:
  enum class Step {
    Ended,      ///< no streak after this match
    Started,    ///< a counting match began a new streak
    Confirmed,  ///< a counting match agreed with the streak
    Continued,  ///< a non-counting match agreed with the streak
  };

  explicit InitializationStreak(InitializationConfig cfg = {}) : cfg_(cfg) {}

  /// Adds the match of one extraction; odometry_distance_m is the distance driven so
  /// far (monotonic).
  Step add(const MatchResult& match, const Pose2& T_odom_vehicle, double odometry_distance_m);

  /// The streak's transform once it has enough confirmations over enough driving (the
  /// last counting match's T_map_odom), else nullopt.
  [[nodiscard]] std::optional<Pose2> ready(double odometry_distance_m) const;

  [[nodiscard]] int confirmations() const { return count_; }
  void reset() { count_ = 0; }

 private:
  InitializationConfig cfg_;
  int count_ = 0;         ///< counting matches in the streak (0: no streak)
  double start_m_ = 0.0;  ///< odometry distance of the streak's first match
  Pose2 T_map_odom_;      ///< the last counting match's transform
};

/// Parameters of the relocalization check's confirmation (LocalizerConfig relocalization_*).
struct RelocalizationConfig {
  /// The wide match has at least this many more associations than the tracking match.
  int extra_matches = 3;
  /// Two checks agree when they put the vehicle within these of each other.
  double agreement_xy_m = 1.0;
  double agreement_yaw_rad = 0.0175;
};

/// The relocalization check's decision: a wide-gate match that counts for initialization,
/// has extra_matches more associations than tracking and lies away from the estimate is a
/// candidate; the next check, if it is one too and agrees with it, confirms it (the
/// Localizer's checks are relocalization_every_n_extractions apart).
class RelocalizationConfirmation {
 public:
  RelocalizationConfirmation(InitializationConfig init = {}, RelocalizationConfig cfg = {})
      : init_(init), cfg_(cfg) {}

  /// One check: `wide` the wide-gate match, `tracking_point_matches` the tracking match's
  /// associations, `distinct` whether wide's vehicle pose is away from the estimate. Returns
  /// the T_map_odom to re-anchor to when this check confirms the previous one.
  std::optional<Pose2> add(const MatchResult& wide, std::size_t tracking_point_matches,
                           bool distinct, const Pose2& T_odom_vehicle);

  [[nodiscard]] bool pending() const { return count_ > 0; }
  void reset() { count_ = 0; }

 private:
  InitializationConfig init_;
  RelocalizationConfig cfg_;
  int count_ = 0;
  Pose2 T_map_odom_;
};

}  // namespace polmap::loc
