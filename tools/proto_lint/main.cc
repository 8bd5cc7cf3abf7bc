// proto_lint: checks the project's contracts against the rules of docs/protocols.md (Buf's
// style, which Debian does not package).
//
//   proto_lint <descriptor_set.pb> [--prefix picking/]
//
// The descriptor set is protoc's (--descriptor_set_out, --include_imports, and
// --include_source_info for line numbers). Prints one line per finding; exits 0 when there
// is none, 1 when there are, 2 when the set cannot be read.
#include <fstream>
#include <iostream>
#include <string>

#include "tools/proto_lint/proto_lint.h"

int main(int argc, char** argv) {
  std::string path;
  picking::proto_lint::Options options;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--prefix" && i + 1 < argc) {
      options.file_prefix = argv[++i];
    } else if (path.empty() && arg.rfind("--", 0) != 0) {
      path = arg;
    } else {
      path.clear();
      break;
    }
  }
  if (path.empty()) {
    std::cerr << "usage: proto_lint <descriptor_set.pb> [--prefix picking/]\n";
    return 2;
  }
  std::ifstream in(path, std::ios::binary);
  google::protobuf::FileDescriptorSet set;
  if (!in || !set.ParseFromIstream(&in)) {
    std::cerr << "proto_lint: cannot read a descriptor set from '" << path << "'\n";
    return 2;
  }
  try {
    const auto findings = picking::proto_lint::Lint(set, options);
    for (const auto& finding : findings) std::cout << ToString(finding) << "\n";
    int linted = 0;
    for (const auto& file : set.file()) linted += file.name().rfind(options.file_prefix, 0) == 0;
    std::cout << "proto_lint: " << linted << " files under '" << options.file_prefix << "', "
              << findings.size() << " findings\n";
    return findings.empty() ? 0 : 1;
  } catch (const std::exception& e) {
    std::cerr << "proto_lint: " << e.what() << "\n";
    return 2;
  }
}
