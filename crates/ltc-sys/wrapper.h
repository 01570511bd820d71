#include <ltc.h>
