%% @doc Internal. The notifier's output: RFC 5322 / MIME e-mail messages
%% (multipart/mixed, a text part and base64 attachments in 76-character
%% lines, CRLF line ends) and SMS text files, written to a spool folder by
%% the caller and never sent anywhere. Header values from requests are
%% stripped of line breaks and encoded (RFC 2047) when not ASCII.
-module(avatar_sim_mail).

-export([email/1, sms/1, rfc5322_date/2]).

-export_type([email/0]).

-type email() :: #{from := binary(), to := binary(), subject := binary(), body := binary(),
                   date := integer(), utc_offset := integer(), message_id := binary(),
                   attachments := [{Filename :: binary(), ContentType :: binary(), binary()}]}.

%% @doc The bytes of an .eml file.
-spec email(email()) -> binary().
email(#{from := From, to := To, subject := Subject, body := Body, date := Date,
        utc_offset := Offset, message_id := Id, attachments := Attachments}) ->
    Boundary = <<"=_evatar_", (binary:encode_hex(crypto:hash(md5, Id)))/binary>>,
    Headers = [{<<"From">>, header(From)}, {<<"To">>, header(To)},
               {<<"Subject">>, header(Subject)}, {<<"Date">>, rfc5322_date(Date, Offset)},
               {<<"Message-ID">>, <<"<", (header(Id))/binary, ">">>},
               {<<"MIME-Version">>, <<"1.0">>},
               {<<"Content-Type">>, <<"multipart/mixed; boundary=\"", Boundary/binary, "\"">>},
               {<<"X-Mailer">>, <<"EVATAR avatar_sim notifier">>}],
    Text = [<<"--">>, Boundary, <<"\r\n">>,
            <<"Content-Type: text/plain; charset=utf-8\r\n">>,
            <<"Content-Transfer-Encoding: base64\r\n\r\n">>, base64_lines(Body)],
    Parts = [[<<"--">>, Boundary, <<"\r\n">>,
              <<"Content-Type: ">>, header(Type), <<"; name=\"">>, filename(Name), <<"\"\r\n">>,
              <<"Content-Transfer-Encoding: base64\r\n">>,
              <<"Content-Disposition: attachment; filename=\"">>, filename(Name), <<"\"\r\n\r\n">>,
              base64_lines(Bytes)]
             || {Name, Type, Bytes} <- Attachments],
    iolist_to_binary([[[K, <<": ">>, V, <<"\r\n">>] || {K, V} <- Headers],
                      <<"\r\nThis is a multipart message in MIME format.\r\n">>,
                      Text, Parts, <<"--">>, Boundary, <<"--\r\n">>]).

%% @doc The bytes of an .sms file.
-spec sms(#{to := binary(), text := binary(), date := integer(), utc_offset := integer()}) ->
          binary().
sms(#{to := To, text := Text, date := Date, utc_offset := Offset}) ->
    iolist_to_binary([<<"To: ">>, header(To), <<"\r\nDate: ">>, rfc5322_date(Date, Offset),
                      <<"\r\n\r\n">>, Text, <<"\r\n">>]).

%% @doc `Fri, 15 Nov 2024 17:05:00 +0000' for ms since 1970 (UTC) shown at
%% `Offset' minutes from UTC.
-spec rfc5322_date(integer(), integer()) -> binary().
rfc5322_date(Ms, Offset) ->
    Secs = Ms div 1000 + Offset * 60
        + calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}}),
    {{Y, Mo, D} = Date, {H, Mi, S}} = calendar:gregorian_seconds_to_datetime(Secs),
    Day = element(calendar:day_of_the_week(Date),
                  {"Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun"}),
    Month = element(Mo, {"Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep",
                         "Oct", "Nov", "Dec"}),
    Sign = case Offset < 0 of true -> $-; false -> $+ end,
    list_to_binary(io_lib:format("~s, ~2..0B ~s ~4..0B ~2..0B:~2..0B:~2..0B ~c~2..0B~2..0B",
                                 [Day, D, Month, Y, H, Mi, S, Sign, abs(Offset) div 60,
                                  abs(Offset) rem 60])).

%% No line breaks may reach a header from a request; anything but printable
%% ASCII is sent as an encoded word.
header(Value) ->
    Flat = << <<(case C of $\r -> $\s; $\n -> $\s; _ -> C end)>> || <<C>> <= Value >>,
    case lists:all(fun(C) -> C >= 32 andalso C < 127 end, binary_to_list(Flat)) of
        true -> Flat;
        false -> <<"=?UTF-8?B?", (base64:encode(Flat))/binary, "?=">>
    end.

filename(Name) ->
    << <<C>> || <<C>> <= Name, C > 32, C < 127, C =/= $", C =/= $\\, C =/= $/ >>.

base64_lines(Bytes) ->
    lines(base64:encode(Bytes)).

lines(<<Line:76/binary, Rest/binary>>) when Rest =/= <<>> -> [Line, <<"\r\n">> | lines(Rest)];
lines(Line) -> [Line, <<"\r\n">>].
