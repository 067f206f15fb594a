#include "stages/relight/relight_matrix.h"

#include "format/io/container_reader.h"
#include "stages/common/basis.h"
#include "stages/common/channels.h"

namespace ltb::stages {

Result<RelightMatrix> RelightMatrix::OpenSet(const std::string& path, const std::vector<SetMember>& members,
                                             uint64_t mem_limit, int jobs, const Progress& progress,
                                             nlohmann::json* report) {
  RelightMatrix m;
  m.path_ = path;
  m.jobs_ = jobs;
  m.progress_ = progress;
  nlohmann::json channels = nlohmann::json::array();
  if (members.size() != static_cast<size_t>(kChannels) || members.front().name != "r") {
    return InvalidArgument(path + ": is the set of " + members.front().path + ", the " +
                           std::to_string(members.size()) +
                           " terms of a factored bake: their image depends on the view; relight it with --eye "
                           "(docs/GLOSSY.md)");
  }
  for (const SetMember& member : members) {
    const std::string& f = member.path;
    nlohmann::json one = nlohmann::json::object();
    LTB_ASSIGN_OR_RETURN(RelightMatrix c, Open(f, mem_limit, jobs, progress, &one));
    if (!m.channels_.empty()) {
      const RelightMatrix& first = m.channels_.front();
      if (c.rows() != first.rows() || c.basis().cube_res() != first.basis().cube_res() || c.width() != first.width() ||
          c.height() != first.height() || c.streamed() != first.streamed()) {
        return InvalidArgument(f + ": is not the same kind of matrix as " + first.path() + " (rows " +
                               std::to_string(c.rows()) + " vs " + std::to_string(first.rows()) + ", R " +
                               std::to_string(c.basis().cube_res()) + " vs " +
                               std::to_string(first.basis().cube_res()) +
                               "): the channels of a set must come from one bake through the same stages");
      }
    }
    channels.push_back(one);
    m.channels_.push_back(std::move(c));
  }
  const RelightMatrix& first = m.channels_.front();
  m.rows_ = first.rows_;
  m.width_ = first.width_;
  m.height_ = first.height_;
  m.basis_ = first.basis_;
  m.mask_ = first.mask_;
  if (report != nullptr) {
    (*report)["channels"] = channels;
    uint64_t bytes = 0;
    for (const auto& c : channels) bytes += c.value("matrix_bytes_in_memory", uint64_t{0});
    if (bytes > 0) (*report)["matrix_bytes_in_memory"] = bytes;
  }
  return m;
}

Result<RelightMatrix> RelightMatrix::Open(const std::string& path, uint64_t mem_limit, int jobs,
                                          const Progress& progress, nlohmann::json* report) {
  LTB_ASSIGN_OR_RETURN(std::vector<SetMember> members, ChannelFiles(path));
  if (!members.empty()) return OpenSet(path, members, mem_limit, jobs, progress, report);
  LTB_ASSIGN_OR_RETURN(io::ContainerReader reader, io::ContainerReader::Open(path));
  RelightMatrix m;
  m.path_ = path;
  m.jobs_ = jobs;
  m.progress_ = progress;
  LTB_ASSIGN_OR_RETURN(m.basis_, LightingBasis::FromMetadata(reader.metadata(), path));
  const bool is_cpca = CpcaModel::IsCpca(reader.metadata());
  const bool streaming = !is_cpca && reader.metadata().matrix().layout == format::Layout::kRows;
  m.rows_ = reader.metadata().matrix().rows;
  nlohmann::json unused;
  if (report == nullptr) report = &unused;
  if (is_cpca) {  // clustered PCA: project the lighting per cluster, blend per row
    LTB_ASSIGN_OR_RETURN(CpcaRelighter r, CpcaRelighter::Load(path, mem_limit));
    m.cpca_ = std::move(r);
    m.rows_ = m.cpca_->rows();
    (*report)["cpca"] = {{"clusters", m.cpca_->model().clusters()}, {"basis", m.cpca_->model().basis()}};
    (*report)["matrix_bytes_in_memory"] = m.cpca_->bytes();
    if (auto img = m.cpca_->model().image()) {
      m.width_ = img->first;
      m.height_ = img->second;
    }
  } else if (!streaming) {
    LTB_ASSIGN_OR_RETURN(Relighter r, Relighter::Load(path, mem_limit, progress, jobs));
    m.relighter_ = std::move(r);
    (*report)["nonzeros"] = m.relighter_->nonzeros();
    (*report)["matrix_bytes_in_memory"] = m.relighter_->bytes();
    m.width_ = m.relighter_->image_width();
    m.height_ = m.relighter_->image_height();
  } else if (auto img = ReadImageRows(reader.metadata())) {
    m.width_ = img->width;
    m.height_ = img->height;
  }
  LTB_ASSIGN_OR_RETURN(m.mask_, ReadRowMask(reader));
  LTB_ASSIGN_OR_RETURN(m.reflectance_, ReadRowReflectance(reader, m.rows_));
  return m;
}

const std::vector<double>& RelightMatrix::column_norms() const {
  if (!channels_.empty()) return channels_[0].column_norms();
  static const std::vector<double> kNoNorms;
  return relighter_ ? relighter_->column_norms() : kNoNorms;
}

template <typename F>
Status RelightMatrix::PerChannel(std::vector<float>* image, F relight_one) {
  image->assign(rows_ * 3, 0.0f);
  std::vector<float> one;
  for (size_t c = 0; c < channels_.size(); ++c) {
    LTB_RETURN_IF_ERROR(relight_one(channels_[c], &one));
    for (uint64_t r = 0; r < rows_; ++r) (*image)[3 * r + c] = one[3 * r + c];
  }
  return Status::Ok();
}

Status RelightMatrix::Relight(const LightTerms& terms, std::vector<float>* image) {
  if (!channels_.empty()) {
    return PerChannel(image, [&](RelightMatrix& m, std::vector<float>* one) { return m.Relight(terms, one); });
  }
  image->resize(rows_ * 3);
  if (relighter_) {
    relighter_->Relight(terms, image->data());
  } else if (cpca_) {
    cpca_->RelightTerms(terms.column, terms.rgb, image->data());
  } else {
    std::vector<float> dense(6 * basis_.cube_res() * basis_.cube_res() * 3, 0.0f);
    for (size_t k = 0; k < terms.column.size(); ++k)
      for (int c = 0; c < 3; ++c) dense[terms.column[k] * 3 + c] = terms.rgb[k * 3 + c];
    return RelightDense(dense, image);
  }
  ApplyReflectance(reflectance_, image);
  return Status::Ok();
}

Status RelightMatrix::RelightDense(const std::vector<float>& lighting, std::vector<float>* image) {
  if (!channels_.empty()) {
    return PerChannel(image, [&](RelightMatrix& m, std::vector<float>* one) { return m.RelightDense(lighting, one); });
  }
  if (relighter_) {
    LightTerms every;
    LTB_RETURN_IF_ERROR(
        basis_.SelectTerms(lighting.data(), lighting.size() / 3, Weighting::kNone, column_norms(), &every));
    return Relight(every, image);
  }
  if (cpca_) {
    image->resize(rows_ * 3);
    cpca_->Relight(lighting.data(), image->data());
  } else {
    LTB_ASSIGN_OR_RETURN(*image, RelightStreaming(path_, lighting.data(), jobs_, progress_));
  }
  ApplyReflectance(reflectance_, image);
  return Status::Ok();
}

Status CheckSameBake(const RelightMatrix& reference, const RelightMatrix& matrix) {
  if (reference.basis().cube_res() != matrix.basis().cube_res() || reference.rows() != matrix.rows()) {
    return InvalidArgument(reference.path() + ": is not the same bake as " + matrix.path() + " (shape or R differ)");
  }
  if (reference.channel_count() != matrix.channel_count()) {
    return InvalidArgument(reference.path() + ": has " + std::to_string(reference.channel_count()) +
                           " colour channel(s) and " + matrix.path() + " has " +
                           std::to_string(matrix.channel_count()) +
                           "; compare a channel set with a channel set (docs/COLOUR.md)");
  }
  return Status::Ok();
}

}  // namespace ltb::stages
