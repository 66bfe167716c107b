# cmake --install, then find_package(terralign) in another project.
include(CMakePackageConfigHelpers)

install(TARGETS terralign_geo_core terralign_geo terralign_raster terralign_nn terralign_iclk
        EXPORT terralignTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(DIRECTORY src/geo/include/terralign src/raster/include/terralign src/nn/include/terralign src/iclk/include/terralign
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
if(TERRALIGN_BUILD_TOOLS)
  install(TARGETS terralign_cli RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
endif()

install(EXPORT terralignTargets NAMESPACE terralign::
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/terralign)
configure_package_config_file(cmake/terralignConfig.cmake.in
  ${PROJECT_BINARY_DIR}/terralignConfig.cmake
  INSTALL_DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/terralign)
write_basic_package_version_file(${PROJECT_BINARY_DIR}/terralignConfigVersion.cmake
  COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/terralignConfig.cmake
              ${PROJECT_BINARY_DIR}/terralignConfigVersion.cmake
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/terralign)
