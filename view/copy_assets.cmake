# cmake -DSRC=view/web -DDST=<build>/share/flyover/web -P copy_assets.cmake
# Mirrors the page folder into the build tree: DST is replaced so removed files go too.
file(REMOVE_RECURSE "${DST}")
file(MAKE_DIRECTORY "${DST}")
if(EXISTS "${SRC}")
  file(COPY "${SRC}/" DESTINATION "${DST}")
endif()
