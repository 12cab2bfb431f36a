// Splitting one record of a delimited text file into fields, as RFC 4180 reads CSV.
//
// A field may be wrapped in double quotes; inside them the delimiter and line breaks are text,
// and "" is one quote: `1.0,"a,b",2` is three fields, `"say ""hi"""` reads `say "hi"`. Spaces
// around a field (and around its quotes) are trimmed, as numbers written `, 1.5 ,` need.
// Where RFC 4180 says nothing, this reads as Python's csv module does, which is what most
// vendor tools' files are checked against: a quote inside an unquoted field is text (`a"b`),
// and text after a closing quote is appended (`"a"b` reads `ab`).
//
// Why our own splitter rather than a library: the packaged C++ CSV readers (Debian's
// libfccp-dev, libcsv) read a fixed, compile-time set of columns from a file they open, or call
// back per field with copies; the column importer needs columns named by number or name, the
// file already in memory, views with no allocation per field (a 50,000-row capture), and the
// record's own line number in every error.
#ifndef IMUCAL_IMPORTERS_CSV_FIELDS_H_
#define IMUCAL_IMPORTERS_CSV_FIELDS_H_

#include <deque>
#include <string>
#include <string_view>
#include <vector>

namespace imucal::importers {

// The delimiter that stands for "runs of spaces and tabs" (a whitespace-aligned table).
inline constexpr char kWhitespaceDelimiter = ' ';

// The fields of one record. Views point into the record, or into `unescaped` for a field whose
// text differs from its bytes (a "" inside quotes); they stay valid until the next split.
struct CsvFields {
  std::vector<std::string_view> fields;
  std::deque<std::string> unescaped;  // a deque: adding one never moves the others
};

enum class CsvSplit {
  kOk,
  kOpenQuote,  // the record ends inside quotes: a quoted line break, the record goes on
};

// Splits `record` at `delimiter` (',', ';', '\t', or kWhitespaceDelimiter) into `out`. On
// kOpenQuote `out` holds the fields so far; the caller appends the next line and splits again.
CsvSplit SplitCsvRecord(std::string_view record, char delimiter, CsvFields* out);

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_CSV_FIELDS_H_
