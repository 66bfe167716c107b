#include <cmath>
#include <filesystem>
#include <iterator>

#include <doctest/doctest.h>

#include <terralign/geo/file.hpp>
#include <terralign/geo/image_io.hpp>

#include "support.hpp"

using namespace terralign;
using namespace terralign::geo;
using terralign::test::temp_dir;
using terralign::test::write_text;

TEST_CASE("PFM round trip keeps every float, NaN included, and rows in order") {
  ImageF depth(5, 3, 1);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 5; ++x) depth.at(x, y) = 100.0f * static_cast<float>(y) + static_cast<float>(x) + 0.125f;
  depth.at(2, 1) = NAN;
  const std::string path = temp_dir() + "/depth.pfm";
  REQUIRE(save_pfm(path, depth.view()).ok());
  auto back = read_pfm(path);
  REQUIRE(back.ok());
  REQUIRE(back->width() == 5);
  REQUIRE(back->height() == 3);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 5; ++x) {
      if (x == 2 && y == 1) CHECK(std::isnan(back->at(x, y)));
      else CHECK(back->at(x, y) == depth.at(x, y));
    }
}

TEST_CASE("bad PFM input is refused with the reason") {
  const std::string dir = temp_dir();
  write_text(dir + "/bad_magic.pfm", "P6\n1 1\n-1\n....");
  CHECK(read_pfm(dir + "/bad_magic.pfm").error().message.find("not a PFM") != std::string::npos);
  write_text(dir + "/short.pfm", "Pf\n4 4\n-1\n1234");
  CHECK(read_pfm(dir + "/short.pfm").error().message.find("needs 64") != std::string::npos);
  write_text(dir + "/neg.pfm", "Pf\n-4 4\n-1\n");
  CHECK(read_pfm(dir + "/neg.pfm").error().message.find("-4 x 4") != std::string::npos);
  write_text(dir + "/scale.pfm", "Pf\n1 1\n0\n1234");
  CHECK(read_pfm(dir + "/scale.pfm").error().message.find("scale") != std::string::npos);
  CHECK(!read_pfm(dir + "/none.pfm").ok());
}

TEST_CASE("PNG writing is atomic: a failed write leaves the old file") {
  const std::string path = temp_dir() + "/img.png";
  ImageU8 img(4, 2, 3, 200);
  REQUIRE(save_png(path, img.view()).ok());
  auto back = load_image(path, 3);
  REQUIRE(back.ok());
  CHECK(back->at(3, 1, 2) == 200);
  // Writing into a folder that does not exist fails with the path, and creates nothing.
  auto bad = save_png(temp_dir() + "/no/such/dir/img.png", img.view());
  REQUIRE(!bad.ok());
  CHECK(bad.error().message.find("no/such/dir/img.png") != std::string::npos);
  CHECK(!save_png(path, ImageU8().view()).ok());
  CHECK(load_image(path, 3).ok());  // the earlier good file is intact
}

TEST_CASE("check_writable: a path write_file_atomic can take passes and leaves nothing behind, a folder or a missing folder does not") {
  const std::string dir = temp_dir() + "/writable";
  REQUIRE(std::filesystem::create_directories(dir));
  auto folder_entries = [&] {
    const std::filesystem::directory_iterator all(dir);
    return std::distance(std::filesystem::begin(all), std::filesystem::end(all));
  };
  const std::string path = dir + "/out.json";
  CHECK(check_writable(path).ok());
  CHECK(folder_entries() == 0);  // its probe is gone, and no file was made at the path
  write_text(path, "good");
  CHECK(check_writable(path).ok());
  CHECK(test::read_text(path) == "good");  // an existing file is not touched
  CHECK(folder_entries() == 1);
  const auto folder = check_writable(dir);
  REQUIRE(!folder.ok());
  CHECK(folder.error().message == dir + ": is a directory, not a file");
  const auto missing = check_writable(dir + "/no/such/out.json");
  REQUIRE(!missing.ok());
  CHECK(missing.error().message == dir + "/no/such/out.json: cannot write (No such file or directory)");
}

TEST_CASE("a corrupt image is refused, not decoded") {
  const std::string path = temp_dir() + "/corrupt.png";
  write_text(path, "\x89PNG\r\n\x1a\nnot really");
  auto r = load_image(path);
  REQUIRE(!r.ok());
  CHECK(r.error().message.find("corrupt.png") != std::string::npos);
}
