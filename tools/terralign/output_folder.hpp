// A command's result that is several files belonging together (a flight's frames and lists, a
// dataset's samples and index), put in place whole or not at all.
#pragma once

#include <string>
#include <vector>

#include <terralign/geo/result.hpp>

namespace terralign::cli {

// The command writes into a staging folder inside the output folder; commit() then moves its
// entries over the earlier result's. A run that fails, or is stopped, before commit() leaves the
// earlier result as it was (its staging folder is removed, or by the next run if the process was
// killed). The command names the entries it owns at the folder's top ("frames", "list.txt"):
// commit() replaces those, and removes the ones this run did not write (an earlier flight's
// attitude.txt, say), so that nothing of an earlier result is left beside the new one; the
// folder's other files are never touched.
class OutputFolder {
 public:
  // Makes `folder` if it is missing (its parent must exist) and an empty staging folder in it.
  static Result<OutputFolder> open(const std::string& folder, std::vector<std::string> entries);
  OutputFolder(OutputFolder&& o) noexcept;
  OutputFolder& operator=(OutputFolder&&) = delete;
  OutputFolder(const OutputFolder&) = delete;
  OutputFolder& operator=(const OutputFolder&) = delete;
  ~OutputFolder();  // without a commit(): removes the staging folder and what is in it

  // Where to write `name`: an entry, or a path below one ("frames/000001.png").
  std::string path(const std::string& name) const { return stage_ + "/" + name; }
  // Moves the staged entries into the folder. On an error the earlier entries are moved back
  // where it can, and the message names the entry.
  Status commit();

 private:
  OutputFolder(std::string folder, std::string stage, std::vector<std::string> entries)
      : folder_(std::move(folder)), stage_(std::move(stage)), entries_(std::move(entries)) {}
  std::string folder_, stage_;
  std::vector<std::string> entries_;
  bool done_ = false;
};

}  // namespace terralign::cli
