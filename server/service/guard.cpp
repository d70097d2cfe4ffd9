#include "server/service/guard.h"

#include "server/service/log.h"

namespace meshdeform::service {

void log_unexpected_exception(std::string_view where, std::string_view what) {
  log_event(LogLevel::Error, "unexpected_exception",
            LogFields().add("where", where).add("message", what));
}

}  // namespace meshdeform::service
