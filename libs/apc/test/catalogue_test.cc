#include "libs/apc/catalogue.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <sstream>

namespace picking::apc {
namespace {

const std::string kCsv = std::string(PICKING_DATA_DIR) + "/apc2016/items/item_data.csv";
const std::string kHeader =
    "id,name,description,count,bonus,volume,long_side,middle_side,short_side,difficulty\n";

TEST(CatalogueTest, ReadsAllOfficialItems) {
  const Catalogue catalogue = Catalogue::FromCsvFile(kCsv);
  ASSERT_EQ(catalogue.size(), 39u);
  EXPECT_EQ(catalogue.items().front().name, "i_am_a_bunny_book");
  EXPECT_EQ(catalogue.items().back().name, "oral_b_toothbrush_green");
  for (std::size_t i = 0; i < catalogue.size(); ++i) {
    EXPECT_EQ(catalogue.items()[i].id, static_cast<int>(i) + 1);
  }
}

TEST(CatalogueTest, ParsesFieldsAndConvertsCentimetresToMetres) {
  const Catalogue catalogue = Catalogue::FromCsvFile(kCsv);
  const Item& scissors = catalogue.at("fiskars_scissors_red");
  EXPECT_EQ(scissors.id, 15);
  // Quoted field with an escaped quote.
  EXPECT_EQ(scissors.description, "Fiskars Scissors 5\" Blunt Tip - Red");
  EXPECT_EQ(scissors.count, 1);
  EXPECT_EQ(scissors.bonus, 2);  // "+2" in the file.
  EXPECT_DOUBLE_EQ(scissors.volume_cm3, 61.0);
  EXPECT_NEAR(scissors.long_side_m, 0.133, 1e-12);
  EXPECT_NEAR(scissors.middle_side_m, 0.066, 1e-12);
  EXPECT_NEAR(scissors.short_side_m, 0.015, 1e-12);
  EXPECT_EQ(scissors.difficulty, 2);

  const Item& mailer = catalogue.at("scotch_bubble_mailer");
  EXPECT_EQ(mailer.count, 2);
  EXPECT_EQ(mailer.bonus, 0);
  EXPECT_NEAR(mailer.long_side_m, 0.29, 1e-12);  // Integer centimetres.
  EXPECT_EQ(mailer.difficulty, 3);
}

TEST(CatalogueTest, FindReturnsNullForUnknownAndAtThrowsNamingTheItem) {
  const Catalogue catalogue = Catalogue::FromCsvFile(kCsv);
  EXPECT_NE(catalogue.find("dove_beauty_bar"), nullptr);
  EXPECT_EQ(catalogue.find("dove_beauty"), nullptr);
  EXPECT_EQ(catalogue.find(""), nullptr);
  EXPECT_TRUE(catalogue.contains("crayola_24_ct"));
  try {
    catalogue.at("flying_teapot");
    FAIL() << "expected UnknownItemError";
  } catch (const UnknownItemError& e) {
    EXPECT_EQ(e.item_name(), "flying_teapot");
    EXPECT_NE(std::string(e.what()).find("flying_teapot"), std::string::npos);
  }
  // UnknownItemError is an std::invalid_argument.
  EXPECT_THROW(catalogue.at("nothing"), std::invalid_argument);
}

TEST(CatalogueTest, EveryItemIsFoundByItsName) {
  const Catalogue catalogue = Catalogue::FromCsvFile(kCsv);
  for (const Item& item : catalogue.items()) {
    ASSERT_NE(catalogue.find(item.name), nullptr) << item.name;
    EXPECT_EQ(catalogue.find(item.name)->id, item.id);
  }
}

std::string ErrorOf(const std::string& csv) {
  std::istringstream in(csv);
  try {
    Catalogue::FromCsv(in, "items.csv");
  } catch (const CatalogueError& e) {
    return e.what();
  }
  return "";
}

TEST(CatalogueTest, MalformedCsvNamesSourceAndLine) {
  EXPECT_EQ(ErrorOf(""), "items.csv:1: empty catalogue (no header line)");
  EXPECT_NE(ErrorOf("id,name\n").find("items.csv:1: header has 2 columns"), std::string::npos);
  EXPECT_NE(ErrorOf(kHeader).find("no items"), std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,A,1,0,10,1,1,1,1\n2,b,B,1,0,10,1,1\n")
                .find("items.csv:3: record has 8 columns"),
            std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,A,one,0,10,1,1,1,1\n").find("items.csv:2: column count"),
            std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,A,1,0,10,1.5x,1,1,1\n").find("items.csv:2: column long_side"),
            std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,\"unterminated,1,0,10,1,1,1,1\n").find("unterminated"),
            std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,A,1,0,10,1,1,1,1\n1,b,B,1,0,10,1,1,1,1\n").find("duplicate id"),
            std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,A,1,0,10,1,1,1,1\n2,a,B,1,0,10,1,1,1,1\n").find("twice"),
            std::string::npos);
  EXPECT_NE(ErrorOf(kHeader + "1,a,A,1,0,10,0,1,1,1\n").find("positive"), std::string::npos);
}

TEST(CatalogueTest, MissingFileNamesThePath) {
  try {
    Catalogue::FromCsvFile("/nonexistent/items.csv");
    FAIL();
  } catch (const CatalogueError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/items.csv"), std::string::npos);
  }
}

TEST(CatalogueTest, QuotedFieldsMaySpanLinesAndCrlfIsAccepted) {
  std::istringstream in(kHeader + "7,x,\"two\r\nlines, \"\"quoted\"\"\",1,+3,5.5,2,1,0.5,3\r\n");
  const Catalogue catalogue = Catalogue::FromCsv(in, "inline");
  const Item& item = catalogue.at("x");
  EXPECT_EQ(item.description, "two\r\nlines, \"quoted\"");
  EXPECT_EQ(item.bonus, 3);
  EXPECT_DOUBLE_EQ(item.volume_cm3, 5.5);
  EXPECT_EQ(item.difficulty, 3);
}

TEST(CatalogueTest, DefaultPathFollowsEnvironment) {
  ::unsetenv("PICKING_DATA_DIR");
  EXPECT_EQ(DefaultCataloguePath(), kCsv);
  EXPECT_EQ(Catalogue::FromCsvFile(DefaultCataloguePath()).size(), 39u);
  ::setenv("PICKING_DATA_DIR", "/opt/picking/data", 1);
  EXPECT_EQ(DefaultCataloguePath(), "/opt/picking/data/apc2016/items/item_data.csv");
  ::setenv("PICKING_DATA_DIR", "", 1);
  EXPECT_EQ(DefaultCataloguePath(), kCsv);
  ::unsetenv("PICKING_DATA_DIR");
}

}  // namespace
}  // namespace picking::apc
