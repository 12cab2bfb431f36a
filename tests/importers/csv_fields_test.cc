// Tests of the record splitter (importers/csv_fields.h): quotes as RFC 4180 reads them, and the
// cases RFC 4180 leaves open read as Python's csv module reads them.
#include "importers/csv_fields.h"

#include <string>
#include <string_view>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace imucal::importers {
namespace {

using ::testing::ElementsAre;

std::vector<std::string> Split(std::string_view record, char delimiter = ',') {
  CsvFields fields;
  EXPECT_EQ(SplitCsvRecord(record, delimiter, &fields), CsvSplit::kOk) << record;
  return {fields.fields.begin(), fields.fields.end()};
}

TEST(CsvFieldsTest, PlainFieldsAreTrimmedAndEmptyOnesKept) {
  EXPECT_THAT(Split("1.0, 2 ,3"), ElementsAre("1.0", "2", "3"));
  EXPECT_THAT(Split("1.0,,,"), ElementsAre("1.0", "", "", ""));
  EXPECT_THAT(Split(""), ElementsAre(""));
  EXPECT_THAT(Split("a;b", ';'), ElementsAre("a", "b"));
}

TEST(CsvFieldsTest, QuotedDelimiterIsText) {
  EXPECT_THAT(Split("1,\"a,b\",2"), ElementsAre("1", "a,b", "2"));
  EXPECT_THAT(Split("\"a;b\";2", ';'), ElementsAre("a;b", "2"));
  EXPECT_THAT(Split("\"a\tb\"\t2", '\t'), ElementsAre("a\tb", "2"));
}

TEST(CsvFieldsTest, DoubledQuoteInsideQuotesIsOneQuote) {
  EXPECT_THAT(Split("\"say \"\"hi\"\"\",1"), ElementsAre("say \"hi\"", "1"));
  EXPECT_THAT(Split("\"\"\"\""), ElementsAre("\""));
  EXPECT_THAT(Split("\"\",x"), ElementsAre("", "x"));
}

TEST(CsvFieldsTest, SpacesAroundQuotesAreTrimmedInsideKept) {
  EXPECT_THAT(Split("  \" a \"  ,1"), ElementsAre(" a ", "1"));
  EXPECT_THAT(Split("\"1.5\""), ElementsAre("1.5"));
}

TEST(CsvFieldsTest, StrayQuotesReadAsPythonCsvDoes) {
  EXPECT_THAT(Split("a\"b,c"), ElementsAre("a\"b", "c"));  // a quote mid-field is text
  EXPECT_THAT(Split("\"a\"b,c"), ElementsAre("ab", "c"));  // text after a closing quote joins
}

TEST(CsvFieldsTest, WhitespaceDelimiterKeepsQuotedSpaces) {
  EXPECT_THAT(Split("  1.0   \"a b\"\t2 ", kWhitespaceDelimiter), ElementsAre("1.0", "a b", "2"));
  EXPECT_THAT(Split("   ", kWhitespaceDelimiter), ElementsAre());
}

TEST(CsvFieldsTest, OpenQuoteAsksForTheNextLine) {
  CsvFields fields;
  EXPECT_EQ(SplitCsvRecord("1,\"two\nlines", ',', &fields), CsvSplit::kOpenQuote);
  EXPECT_EQ(SplitCsvRecord("1,\"two\nlines\",3", ',', &fields), CsvSplit::kOk);
  EXPECT_THAT(fields.fields, ElementsAre("1", "two\nlines", "3"));
}

TEST(CsvFieldsTest, UnescapedFieldsStayValidTogether) {
  CsvFields fields;
  ASSERT_EQ(SplitCsvRecord("\"a\"\"\",\"b\"\"\",\"c\"\"\"", ',', &fields), CsvSplit::kOk);
  EXPECT_THAT(fields.fields, ElementsAre("a\"", "b\"", "c\""));
}

}  // namespace
}  // namespace imucal::importers
