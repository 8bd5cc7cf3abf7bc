#include "libs/apc/task.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "libs/apc/bins.h"

namespace picking::apc {
namespace {

using nlohmann::json;

constexpr const char* kBinContents = "bin_contents";
constexpr const char* kToteContents = "tote_contents";
constexpr const char* kWorkOrder = "work_order";

std::string Describe(const json& value) {
  switch (value.type()) {
    case json::value_t::null:
      return "null";
    case json::value_t::object:
      return "an object";
    case json::value_t::array:
      return "an array";
    case json::value_t::string:
      return "a string";
    case json::value_t::boolean:
      return "a boolean";
    default:
      return "a number";
  }
}

class Parser final {
 public:
  Parser(const Catalogue& catalogue, const std::string& source)
      : catalogue_(catalogue), source_(source) {}

  [[noreturn]] void Fail(const std::string& field, const std::string& what) const {
    throw TaskFileError(source_, field, what);
  }

  json ParseJson(const std::string& text) const {
    // Duplicate keys would silently drop data; track the keys of every open object.
    std::vector<std::set<std::string>> open_objects;
    std::string duplicate;
    const json::parser_callback_t callback = [&](int /*depth*/, json::parse_event_t event,
                                                 json& parsed) {
      if (event == json::parse_event_t::object_start) {
        open_objects.emplace_back();
      } else if (event == json::parse_event_t::object_end) {
        if (!open_objects.empty()) open_objects.pop_back();
      } else if (event == json::parse_event_t::key && !open_objects.empty()) {
        const std::string key = parsed.get<std::string>();
        if (!open_objects.back().insert(key).second && duplicate.empty()) duplicate = key;
      }
      return true;
    };
    json document;
    try {
      document = json::parse(text, callback);
    } catch (const json::parse_error& e) {
      // e.byte is 1-based position of the offending character.
      const std::size_t end = std::min<std::size_t>(e.byte == 0 ? 0 : e.byte - 1, text.size());
      int line = 1;
      std::size_t line_start = 0;
      for (std::size_t i = 0; i < end; ++i) {
        if (text[i] == '\n') {
          ++line;
          line_start = i + 1;
        }
      }
      const std::size_t column = end - line_start + 1;
      std::string detail = e.what();
      const std::size_t colon = detail.find(": ");
      if (colon != std::string::npos) detail = detail.substr(colon + 2);
      throw TaskFileError(source_, "",
                          "line " + std::to_string(line) + ", column " + std::to_string(column) +
                              ": malformed JSON: " + detail);
    }
    if (!duplicate.empty()) Fail(duplicate, "key \"" + duplicate + "\" appears twice");
    return document;
  }

  std::vector<std::string> ItemList(const json& value, const std::string& field) const {
    if (!value.is_array()) Fail(field, "expected an array of item names, got " + Describe(value));
    std::vector<std::string> items;
    items.reserve(value.size());
    for (std::size_t i = 0; i < value.size(); ++i) {
      const std::string element = field + "[" + std::to_string(i) + "]";
      items.push_back(ItemName(value[i], element));
    }
    return items;
  }

  std::string ItemName(const json& value, const std::string& field) const {
    if (!value.is_string()) Fail(field, "expected an item name, got " + Describe(value));
    std::string name = value.get<std::string>();
    if (!catalogue_.contains(name)) Fail(field, "unknown item \"" + name + "\"");
    return name;
  }

  Task Run(const std::string& text) const {
    const json document = ParseJson(text);
    if (!document.is_object()) Fail("", "top level must be an object, got " + Describe(document));
    for (const auto& [key, value] : document.items()) {
      if (key != kBinContents && key != kToteContents && key != kWorkOrder) {
        Fail(key, "unknown key (expected bin_contents, tote_contents, work_order)");
      }
    }
    Task task;
    task.kind = document.contains(kWorkOrder) ? TaskKind::kPick : TaskKind::kStow;

    if (!document.contains(kBinContents)) Fail(kBinContents, "missing");
    const json& bins = document.at(kBinContents);
    if (!bins.is_object()) Fail(kBinContents, "expected an object, got " + Describe(bins));
    for (const auto& [key, value] : bins.items()) {
      const std::string field = std::string(kBinContents) + "." + key;
      if (!IsBinName(key)) Fail(field, "unknown bin (expected bin_A .. bin_L)");
      task.bin_contents[key] = ItemList(value, field);
    }
    for (int i = 0; i < kNumBins; ++i) {
      const std::string bin = BinName(i);
      if (task.bin_contents.count(bin) == 0) {
        Fail(std::string(kBinContents) + "." + bin, "missing (all 12 bins are required)");
      }
    }

    if (!document.contains(kToteContents)) Fail(kToteContents, "missing");
    task.tote_contents = ItemList(document.at(kToteContents), kToteContents);

    if (task.kind == TaskKind::kPick) {
      const json& order = document.at(kWorkOrder);
      if (!order.is_array()) Fail(kWorkOrder, "expected an array, got " + Describe(order));
      for (std::size_t i = 0; i < order.size(); ++i) {
        const std::string field = std::string(kWorkOrder) + "[" + std::to_string(i) + "]";
        const json& entry = order[i];
        if (!entry.is_object()) Fail(field, "expected an object, got " + Describe(entry));
        for (const auto& [key, value] : entry.items()) {
          if (key != "bin" && key != "item") Fail(field + "." + key, "unknown key");
        }
        if (!entry.contains("bin")) Fail(field + ".bin", "missing");
        if (!entry.contains("item")) Fail(field + ".item", "missing");
        const json& bin = entry.at("bin");
        if (!bin.is_string()) Fail(field + ".bin", "expected a bin name, got " + Describe(bin));
        WorkOrderEntry parsed;
        parsed.bin = bin.get<std::string>();
        if (!IsBinName(parsed.bin)) {
          Fail(field + ".bin", "unknown bin \"" + parsed.bin + "\" (expected bin_A .. bin_L)");
        }
        parsed.item = ItemName(entry.at("item"), field + ".item");
        const auto& contents = task.bin_contents.at(parsed.bin);
        const auto available = std::count(contents.begin(), contents.end(), parsed.item);
        const auto ordered = std::count(task.work_order.begin(), task.work_order.end(), parsed) + 1;
        if (available < ordered) {
          Fail(field + ".item", "\"" + parsed.item + "\" is not in " + parsed.bin +
                                    (available > 0 ? " as often as the work order asks" : ""));
        }
        task.work_order.push_back(std::move(parsed));
      }
    }
    return task;
  }

 private:
  const Catalogue& catalogue_;
  const std::string& source_;
};

std::string Message(const std::string& source, const std::string& field, const std::string& what) {
  std::string message = source;
  if (!field.empty()) message += ": " + field;
  return message + ": " + what;
}

}  // namespace

TaskFileError::TaskFileError(const std::string& source, const std::string& field,
                             const std::string& what)
    : std::runtime_error(Message(source, field, what)), source_(source), field_(field) {}

Task ParseTask(const std::string& json_text, const Catalogue& catalogue,
               const std::string& source_name) {
  return Parser(catalogue, source_name).Run(json_text);
}

Task ReadTaskFile(const std::string& path, const Catalogue& catalogue) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw TaskFileError(path, "", "cannot open task file");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw TaskFileError(path, "", "read error");
  return ParseTask(text.str(), catalogue, path);
}

std::string SerializeTask(const Task& task) {
  // nlohmann::json keeps object keys sorted; the official key orders (bin_contents <
  // tote_contents < work_order, bin_A < .. < bin_L, bin < item) are alphabetical.
  json bins = json::object();
  for (const auto& [bin, items] : task.bin_contents) {
    if (!IsBinName(bin)) throw std::invalid_argument("task has an unknown bin \"" + bin + "\"");
    bins[bin] = items;
  }
  json document = json::object();
  document[kBinContents] = std::move(bins);
  document[kToteContents] = task.tote_contents;
  if (task.kind == TaskKind::kPick) {
    json order = json::array();
    for (const WorkOrderEntry& entry : task.work_order) {
      order.push_back(json{{"bin", entry.bin}, {"item", entry.item}});
    }
    document[kWorkOrder] = std::move(order);
  }
  return document.dump(4) + "\n";
}

Task ToOutput(Task state) {
  state.kind = TaskKind::kStow;
  state.work_order.clear();
  return state;
}

void WriteTaskFile(const std::string& path, const Task& task) {
  const std::string text = SerializeTask(task);
  static std::atomic<unsigned> counter{0};
  const std::string temp_path =
      path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(counter.fetch_add(1));
  {
    std::ofstream out(temp_path, std::ios::binary | std::ios::trunc);
    if (!out) throw TaskFileError(path, "", "cannot create " + temp_path);
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.flush();
    if (!out) {
      out.close();
      std::remove(temp_path.c_str());
      throw TaskFileError(path, "", "write error");
    }
  }
  if (std::rename(temp_path.c_str(), path.c_str()) != 0) {
    const int error = errno;
    std::remove(temp_path.c_str());
    throw TaskFileError(path, "", std::string("cannot replace the file: ") + std::strerror(error));
  }
}

}  // namespace picking::apc
