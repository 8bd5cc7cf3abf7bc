#pragma once

#include <istream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace picking::apc {

/// One APC 2016 item as listed in the catalogue (data/apc2016/items/item_data.csv).
struct Item {
  int id = 0;                ///< 1-based catalogue id.
  std::string name;          ///< Official item name, e.g. "fiskars_scissors_red".
  std::string description;   ///< Human-readable product name.
  int count = 0;             ///< Copies of the item in the competition set.
  int bonus = 0;             ///< Bonus points for picking or stowing it (0-3).
  double volume_cm3 = 0.0;   ///< Volume, cubic centimetres.
  double long_side_m = 0.0;  ///< Longest box dimension, metres.
  double middle_side_m = 0.0;
  double short_side_m = 0.0;
  int difficulty = 0;  ///< 1 (easy) to 3 (hard).
};

/// Thrown when an item name is not in the catalogue. The message names the item.
class UnknownItemError final : public std::invalid_argument {
 public:
  explicit UnknownItemError(const std::string& item_name);
  const std::string& item_name() const { return item_name_; }

 private:
  std::string item_name_;
};

/// Thrown when a catalogue file cannot be read or is malformed. The message names the source
/// and the line (1-based) and column.
class CatalogueError final : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The set of APC items, looked up by name.
class Catalogue final {
 public:
  /// Builds a catalogue from items; throws std::invalid_argument on an empty or duplicate name,
  /// a duplicate id, negative count/bonus or non-positive dimensions.
  explicit Catalogue(std::vector<Item> items);

  /// Reads a CSV file with the header
  /// `id,name,description,count,bonus,volume,long_side,middle_side,short_side,difficulty`
  /// (dimensions in cm, converted to metres; RFC 4180 quoting; bonus may carry a '+').
  /// Throws CatalogueError naming the file and line on a missing file or malformed content.
  static Catalogue FromCsvFile(const std::string& path);
  /// As FromCsvFile, from a stream; `source_name` is used in error messages.
  static Catalogue FromCsv(std::istream& in, const std::string& source_name);

  /// The item called `name`, or nullptr.
  const Item* find(std::string_view name) const;
  /// The item called `name`; throws UnknownItemError naming it.
  const Item& at(std::string_view name) const;
  bool contains(std::string_view name) const { return find(name) != nullptr; }
  /// All items in catalogue (file) order.
  const std::vector<Item>& items() const { return items_; }
  std::size_t size() const { return items_.size(); }

 private:
  std::vector<Item> items_;
  std::vector<std::size_t> sorted_;  // Indices into items_, sorted by name.
};

/// Path of the bundled APC 2016 catalogue: `$PICKING_DATA_DIR/apc2016/items/item_data.csv`
/// when the environment variable PICKING_DATA_DIR is set and non-empty, otherwise the file in
/// the source tree's data/ folder.
std::string DefaultCataloguePath();

/// The data folder used by DefaultCataloguePath(): `$PICKING_DATA_DIR` or the source tree's
/// data/ folder.
std::string DefaultDataDir();

}  // namespace picking::apc
