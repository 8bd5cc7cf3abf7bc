#include "libs/apc/catalogue.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

#ifndef PICKING_APC_DATA_DIR
#error "PICKING_APC_DATA_DIR must name the source tree's data folder"
#endif

namespace picking::apc {
namespace {

constexpr const char* kHeader[] = {"id",         "name",      "description", "count",
                                   "bonus",      "volume",    "long_side",   "middle_side",
                                   "short_side", "difficulty"};
constexpr std::size_t kNumColumns = sizeof(kHeader) / sizeof(kHeader[0]);
constexpr double kMetresPerCm = 0.01;

[[noreturn]] void Fail(const std::string& source, int line, const std::string& what) {
  throw CatalogueError(source + ":" + std::to_string(line) + ": " + what);
}

// Splits one CSV record (RFC 4180: fields may be quoted, "" inside quotes is a quote).
// Quoted fields may span lines; `line` is advanced accordingly.
bool ReadRecord(std::istream& in, const std::string& source, int* line,
                std::vector<std::string>* fields) {
  fields->clear();
  std::string text;
  if (!std::getline(in, text)) return false;
  ++*line;
  const int start_line = *line;
  std::string field;
  bool quoted = false;
  bool field_was_quoted = false;
  std::size_t i = 0;
  while (true) {
    if (i == text.size()) {
      if (quoted) {
        std::string more;
        if (!std::getline(in, more)) {
          Fail(source, start_line, "unterminated quoted field");
        }
        ++*line;
        field += '\n';
        text = std::move(more);
        i = 0;
        continue;
      }
      break;
    }
    const char c = text[i];
    if (quoted) {
      if (c == '"') {
        if (i + 1 < text.size() && text[i + 1] == '"') {
          field += '"';
          ++i;
        } else {
          quoted = false;
        }
      } else {
        field += c;
      }
    } else if (c == '"') {
      if (!field.empty() || field_was_quoted) {
        Fail(source, *line, "quote inside an unquoted field, column " + std::to_string(i + 1));
      }
      quoted = true;
      field_was_quoted = true;
    } else if (c == ',') {
      fields->push_back(std::move(field));
      field.clear();
      field_was_quoted = false;
    } else if (c == '\r' && i + 1 == text.size()) {
      // Tolerate CRLF line ends.
    } else {
      if (field_was_quoted) {
        Fail(source, *line, "text after a closing quote, column " + std::to_string(i + 1));
      }
      field += c;
    }
    ++i;
  }
  fields->push_back(std::move(field));
  return true;
}

int ParseInt(const std::string& text, const std::string& source, int line, const char* column) {
  std::string_view s = text;
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  int value = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size()) {
    Fail(source, line, std::string("column ") + column + ": \"" + text + "\" is not an integer");
  }
  return value;
}

double ParseDouble(const std::string& text, const std::string& source, int line,
                   const char* column) {
  std::string_view s = text;
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  double value = 0.0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size() || !std::isfinite(value)) {
    Fail(source, line, std::string("column ") + column + ": \"" + text + "\" is not a number");
  }
  return value;
}

}  // namespace

UnknownItemError::UnknownItemError(const std::string& item_name)
    : std::invalid_argument("unknown APC item \"" + item_name + "\""), item_name_(item_name) {}

Catalogue::Catalogue(std::vector<Item> items) : items_(std::move(items)) {
  std::set<int> ids;
  for (const Item& item : items_) {
    const std::string label = "catalogue item \"" + item.name + "\"";
    if (item.name.empty()) throw std::invalid_argument("catalogue item with an empty name");
    if (!ids.insert(item.id).second) {
      throw std::invalid_argument(label + ": duplicate id " + std::to_string(item.id));
    }
    if (item.count < 0) throw std::invalid_argument(label + ": negative count");
    if (item.bonus < 0) throw std::invalid_argument(label + ": negative bonus");
    if (!(item.volume_cm3 > 0.0) || !(item.long_side_m > 0.0) || !(item.middle_side_m > 0.0) ||
        !(item.short_side_m > 0.0)) {
      throw std::invalid_argument(label + ": volume and dimensions must be positive");
    }
  }
  sorted_.resize(items_.size());
  for (std::size_t i = 0; i < items_.size(); ++i) sorted_[i] = i;
  std::sort(sorted_.begin(), sorted_.end(),
            [this](std::size_t a, std::size_t b) { return items_[a].name < items_[b].name; });
  for (std::size_t i = 1; i < sorted_.size(); ++i) {
    if (items_[sorted_[i - 1]].name == items_[sorted_[i]].name) {
      throw std::invalid_argument("catalogue item \"" + items_[sorted_[i]].name +
                                  "\" is listed twice");
    }
  }
}

Catalogue Catalogue::FromCsvFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CatalogueError(path + ": cannot open catalogue file");
  return FromCsv(in, path);
}

Catalogue Catalogue::FromCsv(std::istream& in, const std::string& source_name) {
  int line = 0;
  std::vector<std::string> fields;
  if (!ReadRecord(in, source_name, &line, &fields)) {
    Fail(source_name, 1, "empty catalogue (no header line)");
  }
  if (fields.size() != kNumColumns) {
    Fail(source_name, line,
         "header has " + std::to_string(fields.size()) + " columns, expected " +
             std::to_string(kNumColumns));
  }
  for (std::size_t i = 0; i < kNumColumns; ++i) {
    if (fields[i] != kHeader[i]) {
      Fail(source_name, line,
           "header column " + std::to_string(i + 1) + " is \"" + fields[i] + "\", expected \"" +
               kHeader[i] + "\"");
    }
  }
  std::vector<Item> items;
  while (ReadRecord(in, source_name, &line, &fields)) {
    if (fields.size() == 1 && fields[0].find_first_not_of(" \t\r") == std::string::npos) {
      continue;  // Blank line.
    }
    if (fields.size() != kNumColumns) {
      Fail(source_name, line,
           "record has " + std::to_string(fields.size()) + " columns, expected " +
               std::to_string(kNumColumns));
    }
    Item item;
    item.id = ParseInt(fields[0], source_name, line, "id");
    item.name = fields[1];
    item.description = fields[2];
    item.count = ParseInt(fields[3], source_name, line, "count");
    item.bonus = ParseInt(fields[4], source_name, line, "bonus");
    item.volume_cm3 = ParseDouble(fields[5], source_name, line, "volume");
    item.long_side_m = ParseDouble(fields[6], source_name, line, "long_side") * kMetresPerCm;
    item.middle_side_m = ParseDouble(fields[7], source_name, line, "middle_side") * kMetresPerCm;
    item.short_side_m = ParseDouble(fields[8], source_name, line, "short_side") * kMetresPerCm;
    item.difficulty = ParseInt(fields[9], source_name, line, "difficulty");
    if (item.name.empty()) Fail(source_name, line, "column name: empty item name");
    items.push_back(std::move(item));
  }
  if (items.empty()) Fail(source_name, line, "catalogue has no items");
  try {
    return Catalogue(std::move(items));
  } catch (const std::invalid_argument& e) {
    throw CatalogueError(source_name + ": " + e.what());
  }
}

const Item* Catalogue::find(std::string_view name) const {
  const auto it = std::lower_bound(
      sorted_.begin(), sorted_.end(), name,
      [this](std::size_t index, std::string_view key) { return items_[index].name < key; });
  if (it == sorted_.end() || items_[*it].name != name) return nullptr;
  return &items_[*it];
}

const Item& Catalogue::at(std::string_view name) const {
  const Item* item = find(name);
  if (item == nullptr) throw UnknownItemError(std::string(name));
  return *item;
}

std::string DefaultDataDir() {
  const char* env = std::getenv("PICKING_DATA_DIR");
  if (env != nullptr && env[0] != '\0') return env;
  return PICKING_APC_DATA_DIR;
}

std::string DefaultCataloguePath() { return DefaultDataDir() + "/apc2016/items/item_data.csv"; }

}  // namespace picking::apc
