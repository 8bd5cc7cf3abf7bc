#pragma once

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/apc/catalogue.h"

namespace picking::apc {

/// One line of a pick task's work order: take `item` out of `bin` into the tote.
struct WorkOrderEntry {
  std::string bin;   ///< "bin_A".."bin_L".
  std::string item;  ///< Catalogue item name.

  bool operator==(const WorkOrderEntry& o) const { return bin == o.bin && item == o.item; }
  bool operator!=(const WorkOrderEntry& o) const { return !(*this == o); }
};

/// kPick: a file with a "work_order" key. kStow: a file without one; this also covers every
/// output file (the end state a system reports), which carries only bin and tote contents.
enum class TaskKind { kPick, kStow };

/// An APC 2016 task file (the official JSON format) as data.
///
/// `bin_contents` has exactly the 12 keys bin_A..bin_L; lists hold catalogue item names
/// (repeated names are separate copies; order is kept but carries no meaning).
/// `work_order` is used only when kind == kPick.
struct Task {
  TaskKind kind = TaskKind::kPick;
  std::map<std::string, std::vector<std::string>> bin_contents;
  std::vector<std::string> tote_contents;
  std::vector<WorkOrderEntry> work_order;

  bool operator==(const Task& o) const {
    return kind == o.kind && bin_contents == o.bin_contents && tote_contents == o.tote_contents &&
           work_order == o.work_order;
  }
  bool operator!=(const Task& o) const { return !(*this == o); }
};

/// Thrown for an unreadable, malformed or invalid task file. The message names the file and
/// the field (e.g. "bin_contents.bin_Q", "work_order[3].item") or the line and column of a
/// JSON syntax error.
class TaskFileError final : public std::runtime_error {
 public:
  TaskFileError(const std::string& source, const std::string& field, const std::string& what);
  const std::string& source() const { return source_; }
  /// Dotted path of the offending field; empty for file-level and syntax errors.
  const std::string& field() const { return field_; }

 private:
  std::string source_;
  std::string field_;
};

/// Parses a task from JSON text. The kind is kPick when the top-level object has
/// "work_order", kStow otherwise. Validation (each failure throws TaskFileError naming
/// `source_name` and the field):
/// - well-formed JSON (errors carry line and column), top level an object whose only keys are
///   bin_contents, tote_contents and (optionally) work_order, all of the right JSON types;
/// - bin_contents holds exactly the 12 bins bin_A..bin_L;
/// - every item name is in `catalogue`;
/// - every work-order bin is a bin name and its item is present in that bin (as many times as
///   the work order names that bin and item).
Task ParseTask(const std::string& json_text, const Catalogue& catalogue,
               const std::string& source_name);

/// Reads and parses a task file; throws TaskFileError (also when the file cannot be read).
Task ReadTaskFile(const std::string& path, const Catalogue& catalogue);

/// The official layout: 4-space indent, keys in the order bin_contents, tote_contents,
/// work_order (only for kPick), bins sorted bin_A..bin_L, work-order entries as
/// {"bin", "item"}. Throws std::invalid_argument when a bin key is not a bin name.
std::string SerializeTask(const Task& task);

/// The output-file form of a state: same bin and tote contents, kind kStow and no work
/// order, so that SerializeTask / WriteTaskFile write only bin_contents and tote_contents (the
/// official output format of both tasks).
Task ToOutput(Task state);

/// Writes SerializeTask(task) to `path` atomically: a temporary file in the same folder is
/// written, flushed and renamed over `path`, so readers never see a partial file. Throws
/// TaskFileError when the file cannot be written (and leaves `path` untouched).
void WriteTaskFile(const std::string& path, const Task& task);

}  // namespace picking::apc
