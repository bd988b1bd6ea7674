// Shared by the catalogue's files (src/catalogue/catalogue*.c); not part of the API.
#ifndef MATLABER_CATALOGUE_INTERNAL_H
#define MATLABER_CATALOGUE_INTERNAL_H

#define MLB_CATALOGUE_N_CLASSES 11     // catalogue.c: names; catalogue_shapes.c: builders, same order
#define MLB_CATALOGUE_N_MATERIALS 8

#endif
