// The implementations of Debian's stb_image and stb_image_write headers, compiled once here
// (libstb-dev ships the headers; compiling them in keeps the static library self-contained
// for cross builds). PNG, JPEG and BMP decoders only: the others are not needed.
#define STB_IMAGE_IMPLEMENTATION
#define STBI_ONLY_PNG
#define STBI_ONLY_JPEG
#define STBI_ONLY_BMP
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STBI_WRITE_NO_STDIO
#include <stb/stb_image.h>
#include <stb/stb_image_write.h>
