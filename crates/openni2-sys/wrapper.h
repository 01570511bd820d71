#include <OniCAPI.h>
