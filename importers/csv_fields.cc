#include "importers/csv_fields.h"

#include <algorithm>
#include <cstddef>
#include <string>
#include <string_view>

#include "importers/text_scan.h"

namespace imucal::importers {
namespace {

// Padding before a field: spaces, and tabs unless they are the delimiter.
bool IsPad(char c, char delimiter) { return c == ' ' || (c == '\t' && delimiter != '\t'); }

bool EndsField(char c, char delimiter) {
  return delimiter == kWhitespaceDelimiter ? IsSpace(c) : c == delimiter;
}

// Reads the quoted field whose opening quote is at record[*pos] into `out`; on return *pos is
// where the field ends (a delimiter or the end of the record). False when the quote never closes.
bool ReadQuoted(std::string_view record, char delimiter, size_t* pos, CsvFields* out) {
  size_t i = *pos + 1;
  const size_t content = i;
  bool escaped = false;
  while (true) {
    if (i >= record.size()) return false;
    if (record[i] == '"') {
      if (i + 1 < record.size() && record[i + 1] == '"') {
        escaped = true;
        i += 2;
        continue;
      }
      break;
    }
    ++i;
  }
  const std::string_view inside = record.substr(content, i - content);
  ++i;  // past the closing quote
  size_t tail_end = i;
  while (tail_end < record.size() && !EndsField(record[tail_end], delimiter)) ++tail_end;
  const std::string_view tail = TrimSpaces(record.substr(i, tail_end - i));
  *pos = tail_end;
  if (!escaped && tail.empty()) {
    out->fields.push_back(inside);  // the common case: a view, no copy
    return true;
  }
  std::string& text = out->unescaped.emplace_back();
  text.reserve(inside.size() + tail.size());
  for (size_t k = 0; k < inside.size(); ++k) {
    text.push_back(inside[k]);
    if (inside[k] == '"') ++k;  // "" is one quote
  }
  text.append(tail);
  out->fields.push_back(text);
  return true;
}

CsvSplit SplitAtDelimiter(std::string_view record, char delimiter, CsvFields* out) {
  size_t pos = 0;
  while (true) {
    size_t start = pos;
    while (start < record.size() && IsPad(record[start], delimiter)) ++start;
    if (start < record.size() && record[start] == '"') {
      pos = start;
      if (!ReadQuoted(record, delimiter, &pos, out)) return CsvSplit::kOpenQuote;
    } else {
      pos = std::min(record.find(delimiter, start), record.size());
      out->fields.push_back(TrimSpaces(record.substr(start, pos - start)));
    }
    // A delimiter at the very end still opens one more (empty) field.
    if (pos >= record.size()) return CsvSplit::kOk;
    ++pos;
  }
}

CsvSplit SplitAtSpaces(std::string_view record, CsvFields* out) {
  size_t pos = 0;
  while (true) {
    while (pos < record.size() && IsSpace(record[pos])) ++pos;
    if (pos == record.size()) return CsvSplit::kOk;
    if (record[pos] == '"') {
      if (!ReadQuoted(record, kWhitespaceDelimiter, &pos, out)) return CsvSplit::kOpenQuote;
      continue;
    }
    const size_t start = pos;
    while (pos < record.size() && !IsSpace(record[pos])) ++pos;
    out->fields.push_back(record.substr(start, pos - start));
  }
}

}  // namespace

CsvSplit SplitCsvRecord(std::string_view record, char delimiter, CsvFields* out) {
  out->fields.clear();
  out->unescaped.clear();
  return delimiter == kWhitespaceDelimiter ? SplitAtSpaces(record, out)
                                           : SplitAtDelimiter(record, delimiter, out);
}

}  // namespace imucal::importers
