#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <future>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "libs/apc/catalogue.h"
#include "libs/apc/scoring.h"
#include "libs/apc/task.h"
#include "services/orchestrator/core/cell_port.h"
#include "services/orchestrator/core/journal.h"
#include "services/orchestrator/core/work_list.h"

namespace picking::orchestrator {

/// The steps of the contract's TaskEvent.
enum class Step { kNone, kScan, kDetect, kPlan, kGrasp, kVerify, kPlace };
enum class TaskState { kRunning, kSucceeded, kFailed, kCancelled };

/// What a viewer draws of the step an event ends; empty on most events.
struct EventScene {
  std::vector<Eigen::Vector3f> scan_Base;  ///< A scan view's points, down-sampled.
  bool detected = false;                   ///< The target found at X_BaseItem:
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  double detection_score = 0.0;
  std::string method;
  std::vector<std::array<double, 6>> planned_path_q;  ///< A planned pick's waypoints.
  double head_angle_rad = 0.0;                        ///< The gripper head along them.

  /// The journal's form of the scene (points in millimetres); {} when empty.
  nlohmann::json ToJson() const;
  static EventScene FromJson(const nlohmann::json& json);
};

/// One progress event of a task (journaled, replayed to watchers).
struct TaskEvent {
  std::uint64_t sequence = 0;
  double time_s = 0.0;  ///< Task clock.
  std::string item, from, to;
  Step step = Step::kNone;
  bool ok = true;
  std::string message;
  int items_done = 0, items_total = 0;
  TaskState state = TaskState::kRunning;
  int score = 0;  ///< The rules' score of what has been moved so far.
  double time_limit_s = 0.0;
  EventScene scene;
};

/// At most `max_points` of a view's points, evenly spaced over the cloud's order (an
/// organised cloud keeps its rows' spread); invalid (non-finite) points are left out.
std::vector<Eigen::Vector3f> ThinPoints(const geometry::PointCloud& cloud, std::size_t max_points);

struct PickTaskOptions {
  /// The rules' 15 minutes, in robot time (motion and capture durations as the robot reports
  /// them, plus the wall time of computation the arm waits for).
  double time_limit_s = 900.0;
  /// Attempts per target before it is given up.
  int max_attempts = 2;
  /// A target is skipped when less task time than this is left (about one pick).
  double min_time_per_item_s = 25.0;
  /// A service that does not answer is retried this many times, waiting backoff_s, 2 x, ...
  int service_retries = 3;
  double backoff_s = 0.5;
  /// Where the arm waits at the start and the end.
  std::string home_pose = "home";
  /// Stow: each bin's free volume when empty (m^3), for choosing where an item goes.
  std::map<std::string, double> bin_volume_m3;
  /// Stow: a bin is considered only while its items fill less than this fraction of it.
  double max_bin_fill = 0.6;
  /// After the lift, one view from where the arm is (the wrist camera looks into the
  /// container) and a detection of the target: if it is still where it was found (within
  /// `verify_same_pose_m`), the cup holds something else and it is put back.
  bool verify_after_lift = true;
  double verify_same_pose_m = 0.03;
  /// ... and the held item, at its grasp, must be supported by that view at least this much
  /// (the detector's Verify score) when the view shows it. The pose it hangs at is only known
  /// to the detection's and the contact's error (a centimetre or two), so a right item scores
  /// well below its detection score (0.19-0.23 measured in simulation) while a wrong one
  /// supports almost none of the model (0.04-0.06, with one 0.20): the threshold rejects
  /// only clear mismatches.
  double verify_min_score = 0.1;
  /// ... and the view's points in the space only a held item fills (MeasureHeldSurface: near
  /// the cup, out of the container) must not lie outside the item's box for more than this
  /// fraction of them: the cup holds something larger (two cylinders or two boxes of
  /// different sizes are alike to Verify where they overlap). Judged where the view shows at
  /// least `held_min_points` of that space.
  double held_max_beyond = 0.25;
  int held_min_points = 200;
  /// The guarded move stopping this much sooner than the grasp's surface as detected
  /// (PlannedPick::contact_distance_m) has met something in front of it (a neighbour
  /// standing over the target, or the target is not where it was found): the vacuum is not
  /// tried, so no other item is taken. A detection is off by a centimetre or so.
  double early_contact_m = 0.02;
  /// A contact sooner than the grasp's surface as detected by more than this (but less than
  /// early_contact_m) re-plans the pick for where the cup met it: the item's pose moved back
  /// along the guarded move by the difference. The retreat then starts at the cup; the plan
  /// made for the detected surface would first push the held item on into the bin by the
  /// difference (toward its back wall or neighbours). The new plan is taken when it grasps
  /// the same surface with the same head angle; otherwise the first one is kept. 0: never
  /// re-plan.
  double replan_contact_m = 0.003;
  /// The other items of the target's container are looked for in the same detection, and
  /// the target's pose held against theirs (ResolveAgainstOthers): a target whose every
  /// pose another item fills as well is not taken.
  bool detect_others = true;
  double confusion_overlap = 0.3;
  double confusion_margin = 0.05;
  /// While a target is detected, the arm takes the next target's views (when it lies in
  /// another container, which the pick cannot disturb) and that detection runs while the arm
  /// picks the first. The arm waits only for what detection takes beyond the robot time of
  /// the motions it overlaps.
  bool detect_ahead = true;
  /// Stow: which items are set down on the table and looked at there alone from
  /// `verify_pose` before they are stowed. kInDoubt: an item whose every pose another tote
  /// item fills about as well (see detect_others), which is then taken anyway; kAlways:
  /// every item (the paper's sequence); kNever: an item in doubt is not taken. On the table
  /// an item is stowed as the candidate the view shows best, by at least
  /// `table_identity_margin` of the detection score, or put back into the tote when the view
  /// cannot tell.
  enum class TableCheck { kNever, kInDoubt, kAlways };
  TableCheck table_check = TableCheck::kNever;
  /// Pick: a target in doubt is taken anyway and set down on the table to be told apart
  /// as for a stow (kInDoubt; kAlways counts as kInDoubt): into the tote if it is the
  /// target, back into its bin if it is the other item (the target then tried again later),
  /// back into its bin too if the view cannot tell. kNever: an item in doubt is not taken.
  TableCheck pick_table_check = TableCheck::kNever;
  std::string verify_pose = "verify";
  double table_identity_margin = 0.05;
  /// Pick: a target the planner cannot take because another item of its bin is in the way
  /// (over or beside it: PlannedPick::others_in_the_way) has that item moved into another
  /// bin first, and is tried again at once: up to `max_room_moves` items per target. The
  /// item moved is the one found nearest the target, among those whose box shares at most
  /// `room_max_overlap` of the smaller box with the target's as found (one found in the
  /// target's place may be the target itself); only into bins where no target is left (they
  /// cannot bury one), with room for it (max_bin_fill). The look back checks that the cup
  /// holds it. The output file reports it where it went (the rules do not count moves
  /// between bins against a task).
  bool make_room = true;
  int max_room_moves = 1;
  double room_max_overlap = 0.05;
};

/// What happened to one target.
struct TargetReport {
  std::string item, bin;
  double ease = 0.0;
  int attempts = 0;
  bool picked = false;
  std::string failure;  ///< Last failure, when not picked.
  std::string method;   ///< Detection method that found it.
  double detection_score = 0.0;
  Eigen::Isometry3d X_BaseItem_detected = Eigen::Isometry3d::Identity();
  bool detected = false;
  /// Every pose the last detection gave, the target's and its container's other items',
  /// best first per item (before ResolveAgainstOthers chose): what a person checks when a
  /// target was not taken.
  std::vector<std::pair<std::string, PoseHypothesis>> poses_found;
  std::string grasp;
  double drop_height_m = 0.0;
  std::string placed_in;  ///< The tote, or the bin a stowed item went to.
  /// Task-clock seconds per step name ("scan", "detect", "plan", "grasp", "place").
  std::vector<std::pair<std::string, double>> step_times_s;
};

struct PickTaskResult {
  TaskState state = TaskState::kSucceeded;
  std::string error;               ///< For kFailed.
  apc::Task final_contents;        ///< Where the orchestrator believes the items are.
  std::vector<apc::Event> events;  ///< Moves made, for the score.
  apc::ScoreReport score;          ///< By the rules, from what the orchestrator believes.
  std::vector<TargetReport> targets;
  int items_moved = 0, items_failed = 0;
  double duration_s = 0.0;  ///< Task clock at the end.
};

/// Runs a pick or a stow task: the targets in `order`, each scanned from its container's
/// views, detected, planned, grasped with the guarded move and the vacuum, checked for
/// attachment after the lift, and released over the tote (pick) or into the best bin that a
/// place can be planned into (stow: StowBins). Every physical step is journaled before it starts
/// ("begin") and after ("done"); actions the journal records as done are not repeated (a
/// resumed task). `emit` receives every progress event; `cancel` is polled between steps.
class PickTaskRunner final {
 public:
  PickTaskRunner(apc::Task task, std::vector<Target> order, const apc::Catalogue& catalogue,
                 PickTaskOptions options, CellPort& cell, Journal& journal,
                 std::function<void(const TaskEvent&)> emit, const std::atomic<bool>& cancel);

  PickTaskResult Run();

 private:
  enum class Attempt { kPicked, kFailed, kLostCarried };
  /// A detection running beside the arm: started on the task clock at `clock_s`, it holds
  /// the arm only for the wall time it takes beyond the task clock's advance since then.
  struct PendingDetection {
    std::future<Detection> result;
    std::chrono::steady_clock::time_point started_wall;
    double started_clock_s = 0.0;
  };
  /// A target whose views were taken while another target's detection ran.
  struct Ahead {
    const Target* target = nullptr;
    std::vector<ScanView> views;
    PendingDetection detection;
  };
  /// Why an attempt failed when another item of the bin stands in the target's way: the
  /// items that may be moved aside, best first, and the views they were found in.
  struct InTheWay {
    std::vector<std::string> items;
    std::vector<ScanView> views;
  };
  /// One attempt at `target` (and, when others stand in its way, room made and another
  /// attempt); `next` (may be null) is the target to take views of ahead.
  Attempt TryTarget(Target& target, TargetReport& report, Target* next, TargetReport* next_report);
  /// One attempt: scan (or the views taken ahead), detect, plan, grasp, place. On failure,
  /// `in_the_way` names the items that stood in the way, if that is why. `again`: the same
  /// target right after making room (views taken ahead for the next one are kept).
  Attempt AttemptTarget(Target& target, TargetReport& report, Target* next,
                        TargetReport* next_report, InTheWay* in_the_way, bool again = false);
  /// Moves the first of `in_the_way.items` that can be planned for and placed into a bin
  /// without targets left (RoomBins); true once one is there. Its time counts to `report`.
  bool MakeRoom(Target& target, TargetReport& report, const InTheWay& in_the_way);
  /// The other items of the target's last detection, nearest to the target first.
  std::vector<std::string> NearestOthers(const TargetReport& report) const;
  /// The bins an item moved aside from `from` may go to, roomiest first: none holding a target
  /// not yet done.
  std::vector<std::string> RoomBins(const std::string& item, const std::string& from) const;
  /// The views of the target's container, one per scan pose; false (with the reason in
  /// target.last_failure) when the arm cannot reach one.
  bool ScanViews(Target& target, TargetReport& report, std::vector<ScanView>& views);
  PendingDetection StartDetect(const Target& target, const std::vector<ScanView>& views);
  /// Waits for the detection (retrying a service that did not answer) and holds the target's
  /// pose against the other items found; false with the reason when it is not taken.
  bool FinishDetect(Target& target, TargetReport& report, PendingDetection& pending,
                    const std::vector<ScanView>& views);
  /// Takes the views of `next` and starts its detection, when detect_ahead allows it.
  void ScanAhead(const Target& current, Target& next, TargetReport& next_report);
  /// The first target after index `i` that the current round will try, or npos.
  std::size_t NextInRound(std::size_t i, int round) const;
  Attempt GraspAndPlace(Target& target, TargetReport& report, const PlannedPick& plan,
                        const std::vector<ScanView>& views);
  /// The pick re-planned for the surface where the cup met the item (replan_contact_m), or
  /// `plan` itself.
  PlannedPick ReplanAtContact(Target& target, TargetReport& report, const PlannedPick& plan,
                              const TouchOutcome& touched, const std::vector<ScanView>& views);
  /// Vacuum on, the retreat, the look back and the place, once the cup is on the item.
  Attempt HoldAndPlace(Target& target, TargetReport& report, const PlannedPick& plan,
                       const TouchOutcome& touched);
  /// An item in doubt (rivals_), or every stowed item: set down on the table, identified
  /// there and placed as what it is (or put back where it came from).
  Attempt SetDownAndIdentify(Target& target, TargetReport& report, const PlannedPick& plan);
  /// The item on the table, seen from the verification pose, picked up again and stowed as
  /// the candidate it shows (the first of `candidates` is the one it was taken for).
  Attempt IdentifyAndStow(Target& target, TargetReport& report,
                          const std::vector<std::string>& candidates);
  /// Which of `candidates` the view shows: "" when none, or none clearly ahead; `found` is
  /// its detection.
  std::string IdentifyInView(const std::vector<std::string>& candidates, const ScanView& view,
                             Detection* found, std::string* why);
  /// Plans and takes `item` (found in `view`) from the table: "" once it is held, else why
  /// not (the vacuum let go).
  std::string TakeFromTable(Target& target, TargetReport& report, const std::string& item,
                            const Detection& found, const ScanView& view, PlannedPick* plan);
  /// The held item released into the first of `to` a place can be planned into (the
  /// attempt's journal keys are `target`'s; the contents and the score move `target.item`).
  /// A look back under way (StartLookBack) is judged once the arm is over the destination,
  /// before the release.
  struct PendingLookBack;
  Attempt PlaceHeld(Target& target, TargetReport& report, const PlannedPick& plan,
                    const std::vector<std::string>& to, PendingLookBack* look_back = nullptr);
  /// The target of this task that `item` in `container` stands for (not yet done), or null.
  Target* TargetFor(const std::string& item, const std::string& container);
  /// The look back after the lift, in two halves so that the detectors judge the view while
  /// the arm carries the item on: the view taken (the arm holds still for it) and its
  /// judgement started; then waited for, "" when the held item may be the target (or the
  /// view cannot tell), else why it is not.
  struct LookBackVerdict {
    std::string wrong;         // why the held item is not the target, "" if it may be
    std::string inconclusive;  // why the view could not tell, "" if it could
    std::string measured;      // what the view showed of the held item, for the event
  };
  // The held item judged from the look back's view (Verify, the held item's measure) and
  // whether the target is still where it was found (within verify_same_pose_m of p_found).
  LookBackVerdict JudgeLookBack(const std::string& bin, const std::string& item,
                                const PlannedPick& plan, const ScanView& view,
                                const Eigen::Vector3d& p_found);
  struct PendingLookBack {
    std::future<LookBackVerdict> verdict;  // not valid: no look back under way
  };
  PendingLookBack StartLookBack(Target& target, TargetReport& report, const PlannedPick& plan);
  std::string FinishLookBack(Target& target, TargetReport& report, PendingLookBack* look_back);
  // Why the touch met something other than the target's surface ("" when it may be it).
  std::string EarlyContact(const PlannedPick& plan, const TouchOutcome& touched) const;
  void ResumeFromJournal();
  /// The journal's action records by (type, key).
  using JournalActions = std::map<std::pair<std::string, std::string>, const JournalRecord*>;
  void ResumeRoomMoves(const std::vector<JournalRecord>& records, const JournalActions& actions);
  void FinishCarriedItem();
  /// At resume: `target`'s item, if the cup still holds it, carried on to its destination.
  void FinishCarried(Target& target);
  void FinishItemOnTable();
  void RecordPlaced(const Target& target, const std::string& to, double drop_height_m);
  /// A carried item let go on the way (the arm stopped, the seal gave, a put-back failed):
  /// it has left its container for somewhere outside the bins and the tote, as far as the
  /// task knows, and is no longer reported in it (an output file listing it where it no
  /// longer is would be wrong either way; this is right when it fell to the floor).
  void RecordLost(Target& target, const std::string& reason);
  /// Items this task has let go in `container` so far.
  int PlacedIn(const std::string& container) const;
  /// The distinct items other than `item` that `container` holds now.
  std::vector<std::string> OtherItemsIn(const std::string& container,
                                        const std::string& item) const;
  /// Where the item goes: the tote, or for a stow the bins in order of preference.
  std::vector<std::string> Destinations(const Target& target) const;
  void Emit(const Target* target, Step step, bool ok, const std::string& message,
            const std::string& to = "", EventScene scene = {});
  /// Runs a cell operation, retrying a service that does not answer; rethrows the last error.
  template <typename F>
  auto WithRetries(const std::string& what, F&& operation) -> decltype(operation());
  void AddTime(TargetReport& report, const std::string& step, double seconds);
  double TimeLeft() const { return options_.time_limit_s - clock_s_; }
  std::string Key(const Target& target, const std::string& action) const;

  apc::Task task_;
  apc::Task contents_;
  std::vector<Target> order_;
  const apc::Catalogue& catalogue_;
  PickTaskOptions options_;
  CellPort& cell_;
  Journal& journal_;
  std::function<void(const TaskEvent&)> emit_;
  const std::atomic<bool>& cancel_;
  std::vector<apc::Event> events_;
  double clock_s_ = 0.0;
  int done_ = 0;
  std::uint64_t next_event_ = 0;
  std::string carried_key_;  ///< Journal key prefix of an attempt holding an item at resume.
  std::string table_key_;    ///< ... of an attempt whose item lies on the table at resume.
  std::vector<std::string> table_candidates_;  ///< What that item may be.
  int room_moves_ = 0;  ///< Items moved aside so far (numbers their journal keys).
  /// An item being moved aside that the cup may still hold at resume.
  std::optional<Target> carried_room_;
  std::optional<Ahead> ahead_;
  /// This attempt's target in doubt (table_check, pick_table_check): the items its place may hold
  /// instead, empty when it is not in doubt.
  std::vector<std::string> rivals_;
  std::vector<TargetReport>* reports_ = nullptr;  ///< Run()'s, one per order_ entry.
};

/// The rules' score of what the orchestrator believes happened, with `output` as reported.
apc::ScoreReport ScoreBelief(const apc::Task& initial, const std::vector<apc::Event>& events,
                             const apc::Task& contents, const apc::Catalogue& catalogue);

std::string StepName(Step step);

/// Fraction of the smaller of two item boxes (catalogue sides, centred on the item frame)
/// that lies inside the other, sampled on a grid; 0 for boxes that only touch.
double BoxOverlapFraction(const Eigen::Isometry3d& X_BaseA, const Eigen::Vector3d& size_a_m,
                          const Eigen::Isometry3d& X_BaseB, const Eigen::Vector3d& size_b_m);

/// Two items cannot fill one place, and a flat box matched on another flat box (or a
/// cylinder on another cylinder) scores about as well as on itself: the target's poses are
/// held against the container's other items found in the same detection. A pose of the
/// target is doubtful when another item's best pose takes up its place (at least
/// `min_overlap` of the smaller box inside the other) with a score no worse than the pose's
/// less `margin`. The first pose of the target, best first, that is not doubtful is kept in `found`
/// (its pose and score); "" is returned. When every pose is doubtful, the reason, naming the
/// other item, for the best one.
/// `rivals` (may be null), when every pose is doubtful: the items that fill the best pose's
/// place, in the detection's order.
std::string ResolveAgainstOthers(const std::string& item, Detection* found,
                                 const apc::Catalogue& catalogue, double min_overlap, double margin,
                                 std::vector<std::string>* rivals = nullptr);

/// Stow: the bins an item may go to, best first. A bin is a candidate while its items (their
/// catalogue volumes, the new one included) fill at most `max_fill` of its volume; candidates
/// are ordered by the points a stowed item scores there (the rules' 10 / 15 / 20 by how many
/// items the bin held at the start), then by free volume.
std::vector<std::string> StowBins(const std::string& item, const apc::Task& initial,
                                  const apc::Task& contents, const apc::Catalogue& catalogue,
                                  const std::map<std::string, double>& bin_volume_m3,
                                  double max_fill);

}  // namespace picking::orchestrator
