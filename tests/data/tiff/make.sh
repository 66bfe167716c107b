#!/bin/sh
# Regenerates the GeoTIFF fixtures of the reader tests from the committed NAIP sample with
# GDAL (Debian gdal-bin 3.6), so each layout and codec is written by an independent writer.
# The numbers the tests compare against were printed by gdalinfo / gdallocationinfo on these
# files (see tests/test_geotiff.cpp). Run from this folder: sh make.sh
set -eu
src=../../../data/naip_west/naip_2016.tif
win="-srcwin 300 400 40 30"
t="gdal_translate -q $win"
$t -co COMPRESS=NONE -co TILED=NO -co BLOCKYSIZE=7 $src rgb_strips_none.tif
$t -co COMPRESS=LZW -co TILED=NO $src rgb_strips_lzw.tif
$t -co COMPRESS=DEFLATE -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16 $src rgb_tiles_deflate.tif
$t -co COMPRESS=JPEG -co PHOTOMETRIC=YCBCR -co JPEG_QUALITY=95 -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16 $src rgb_tiles_jpeg.tif
$t -co COMPRESS=PACKBITS -co INTERLEAVE=BAND $src rgb_separate_packbits.tif
$t -mo AREA_OR_POINT=Point -co COMPRESS=DEFLATE $src rgb_pixel_is_point.tif
$t -b 1 -b 2 -b 3 -b mask -co ALPHA=YES -co COMPRESS=DEFLATE $src rgba.tif
$t -b 1 -ot Int16 -scale 0 255 -100 400 -a_nodata -32768 -co COMPRESS=DEFLATE $src dem_int16.tif
$t -b 1 -ot Float32 -scale 0 255 400.5 655.5 -a_nodata nan -co COMPRESS=LZW -co PREDICTOR=3 $src dem_float32.tif
$t -b 1 -ot Float64 $src dem_float64.tif
$t -a_srs EPSG:4326 -a_ullr -99.2 47.1 -99.1 47.0 $src geographic.tif
$t -b 1 -b 2 -co COMPRESS=DEFLATE $src two_bands.tif
$t -b 1 -ot Float32 -scale 0 255 7 7 -a_nodata 7 $src dem_all_nodata.tif
$t -a_srs EPSG:32633 -co COMPRESS=DEFLATE $src rgb_utm33.tif
# Plain PNG with neither a world file nor a transform.
gdal_translate -q $win -of PNG $src no_georef.png
rm -f *.aux.xml
