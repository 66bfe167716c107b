#include "output_folder.hpp"

#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <system_error>
#include <unistd.h>

#include "args.hpp"

namespace terralign::cli {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStage = ".terralign-part-";  // a run's files before its commit
constexpr const char* kAside = ".terralign-old-";   // an earlier result's entries during a commit

bool present(const fs::path& p) {
  std::error_code ec;
  return fs::symlink_status(p, ec).type() != fs::file_type::not_found && !ec;
}

// An empty folder at `path`, whatever was there (a staging or aside folder of this process's pid).
Status fresh_folder(const std::string& path) {
  std::error_code ec;
  fs::remove_all(path, ec);
  if (ec || !fs::create_directory(path, ec) || ec) return Error{path + ": cannot create (" + ec.message() + ")"};
  return Ok{};
}

// Removes the staging folders of runs that were killed before they could (their process is gone).
void remove_leftovers(const std::string& folder) {
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    for (const char* prefix : {kStage, kAside}) {
      const std::string p = prefix;
      if (name.compare(0, p.size(), p) != 0) continue;
      char* tail = nullptr;
      const long pid = std::strtol(name.c_str() + p.size(), &tail, 10);
      if (pid <= 0 || *tail != '\0' || pid == static_cast<long>(::getpid())) continue;
      if (::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
        std::error_code ignored;
        fs::remove_all(it->path(), ignored);
      }
    }
  }
}

}  // namespace

Result<OutputFolder> OutputFolder::open(const std::string& folder, std::vector<std::string> entries) {
  if (auto st = ensure_dir(folder); !st.ok()) return st.error();
  remove_leftovers(folder);
  const std::string stage = folder + "/" + kStage + std::to_string(::getpid());
  if (auto st = fresh_folder(stage); !st.ok()) return st.error();
  return OutputFolder(folder, stage, std::move(entries));
}

OutputFolder::OutputFolder(OutputFolder&& o) noexcept
    : folder_(std::move(o.folder_)), stage_(std::move(o.stage_)), entries_(std::move(o.entries_)), done_(o.done_) {
  o.done_ = true;  // the moved-from object owns no staging folder
}

OutputFolder::~OutputFolder() {
  if (done_) return;
  std::error_code ignored;
  fs::remove_all(stage_, ignored);
}

Status OutputFolder::commit() {
  const std::string aside = folder_ + "/" + kAside + std::to_string(::getpid());
  if (auto st = fresh_folder(aside); !st.ok()) return st;
  std::error_code ec;
  struct Move {
    fs::path final, staged, old;
    bool old_moved = false, new_moved = false;
  };
  std::vector<Move> moves;
  std::string failure;
  for (const std::string& e : entries_) {
    Move m{fs::path(folder_) / e, fs::path(stage_) / e, fs::path(aside) / e};
    if (present(m.final)) {
      fs::rename(m.final, m.old, ec);
      if (ec) {
        failure = m.final.string() + ": cannot move the earlier result's aside (" + ec.message() + ")";
        break;
      }
      m.old_moved = true;
    }
    moves.push_back(m);
    if (present(m.staged)) {
      fs::rename(m.staged, m.final, ec);
      if (ec) {
        failure = m.final.string() + ": cannot put the new result in place (" + ec.message() + ")";
        break;
      }
      moves.back().new_moved = true;
    }
  }
  std::error_code ignored;
  if (!failure.empty()) {
    // Back as it was, as far as the file system lets us: the new entries to the staging
    // folder (removed with it), the earlier ones to their places.
    for (auto m = moves.rbegin(); m != moves.rend(); ++m) {
      if (m->new_moved) fs::rename(m->final, m->staged, ignored);
      if (m->old_moved) fs::rename(m->old, m->final, ignored);
    }
    fs::remove(aside, ignored);  // only if empty: an entry that could not go back stays there
    return Error{failure};
  }
  fs::remove_all(aside, ignored);
  fs::remove_all(stage_, ignored);
  done_ = true;
  return Ok{};
}

}  // namespace terralign::cli
